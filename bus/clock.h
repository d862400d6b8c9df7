#pragma once

// The time the bus's timers read (docs/design.md, "Processes, nodes and time"): programs use the
// process's steady clock, tests drive a ManualClock and sleep nowhere. Only elapsed time is ever
// read from a clock (timeouts, periods, back-off), never the time of day.

#include <atomic>
#include <chrono>

namespace stackgen {

/// A monotonic clock.
class Clock {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  virtual ~Clock() = default;
  virtual TimePoint Now() const = 0;
};

/// std::chrono::steady_clock, one for the process (what a null Clock* in options means).
Clock& SteadyClock();

/// A clock that moves only when told to: tests advance it past a timeout instead of sleeping.
/// Starts at an arbitrary fixed point; may be read from other threads while it is advanced.
class ManualClock : public Clock {
 public:
  TimePoint Now() const override { return TimePoint(Duration(ticks_.load())); }
  /// Moves the clock on by `seconds` (>= 0).
  void Advance(double seconds) {
    ticks_ += std::chrono::duration_cast<Duration>(std::chrono::duration<double>(seconds)).count();
  }

 private:
  using Duration = TimePoint::duration;
  std::atomic<Duration::rep> ticks_{
      std::chrono::duration_cast<Duration>(std::chrono::hours(24)).count()};
};

}  // namespace stackgen
