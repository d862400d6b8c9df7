#pragma once

// What stackgen-monitor knows of a run: the latest status of every process on the bus
// (STACKGEN_STATUS), and how it writes them as Prometheus metrics and as JSON for its page.

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <string>

#include <stackgen/learner_status.hpp>
#include <stackgen/status.hpp>

namespace stackgen {

/// The monitor's own counters of what it heard (its bus's).
struct MonitorCounters {
  int64_t status_messages = 0;    // statuses heard
  int64_t bad_messages = 0;       // messages that did not decode, skipped
  int64_t refused_unsigned = 0;   // refused by the bus key check (bus/auth.h), by reason
  int64_t refused_forged = 0;
  int64_t refused_replayed = 0;
  int64_t refused_relayed = 0;
};

/// The latest status of each process heard, by its name, with when it was heard. Bounded: at
/// most kMaxProcesses names; past that the one heard from least recently goes (a stranger who
/// varies names cannot grow it). Not thread-safe.
class ProcessTable {
 public:
  static constexpr size_t kMaxProcesses = 1024;

  /// Keeps `message` as its process's latest, heard at `now_s` (any monotonic clock, seconds).
  void Update(const status& message, double now_s);

  /// Rates kept per process for the page's sparkline: the last this many statuses' rate_hz.
  static constexpr size_t kRateHistory = 120;

  struct Entry {
    status latest;
    double heard_s = 0;             // when it was last heard
    std::deque<double> rate_hz;     // its last kRateHistory rates, oldest first
  };
  const std::map<std::string, Entry>& entries() const { return entries_; }

  /// Keeps a learner's latest progress (STACKGEN_LEARNER), heard at `now_s`; bounded as the
  /// processes are.
  void UpdateLearner(const learner_status& message, double now_s);
  struct Learner {
    learner_status latest;
    double heard_s = 0;
    std::deque<double> loss;  // its last kRateHistory losses, oldest first
  };
  const std::map<std::string, Learner>& learners() const { return learners_; }

  /// The run of generator `generator_id` (RunName of its STACKGEN_CONFIG), for the `run` label
  /// of its metrics; at most kMaxProcesses generators (later ones go unlabelled).
  void SetRun(int32_t generator_id, const std::string& run);
  /// The run of `generator_id`, or "" when not heard.
  std::string RunOf(int32_t generator_id) const;

 private:
  std::map<std::string, Entry> entries_;
  std::map<std::string, Learner> learners_;
  std::map<int32_t, std::string> runs_;
};

/// A process counts as quiet when it has not been heard for this long (statuses come at 1 Hz),
/// unless its run ended or stopped (it says so as it exits).
inline constexpr double kQuietAfterS = 5;

/// The Prometheus text exposition (version 0.0.4) of `table` at `now_s`, and of the monitor's
/// own `counters`: per process (labels process, name, and generator_id and run for generators,
/// run once its config was heard) its
/// counters as `_total` counters, its gauges, its stage times in seconds, how long since it was
/// heard and whether it is quiet; per learner (labels process, name) its steps, loss, scenes
/// taken and per second, reuse, run state and last heard; every family with its HELP and TYPE,
/// label values escaped as the format says (backslash, double quote, newline).
std::string PrometheusText(const ProcessTable& table, const MonitorCounters& counters,
                           double now_s);

/// The table as JSON for the page (an array of objects, one per process, by name: process,
/// name, generator_id, scenes, rate_hz, rate_history, the stage times, lost, resent,
/// held_back_s, refused, run_state, age_s, quiet), the learners (process, name, steps,
/// target_steps, loss, loss_history, scenes_taken, scenes_per_second, reuse, run_state, age_s,
/// quiet), and the monitor's counters.
std::string StatusJson(const ProcessTable& table, const MonitorCounters& counters, double now_s);

}  // namespace stackgen
