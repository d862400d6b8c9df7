#pragma once

#include <cstdint>
#include <memory>
#include <string>

namespace stackgen::feed {

/// What a learner says of itself (learner_status.lcm).
struct LearnerReport {
  int64_t steps = 0;
  int64_t target_steps = 0;
  double loss = 0;  // NaN before the first step
  int64_t scenes_taken = 0;
  double scenes_per_second = 0;
  double reuse = 0;
};

/// Publishes a learner's progress on STACKGEN_LEARNER from a thread of its own (which also
/// answers the bus key's liveness checks, so keyed listeners take its messages): the latest
/// report about once a second, and a last one, with its run state, when closed. Report is
/// thread-safe and cheap (it only keeps the values).
class LearnerPublisher {
 public:
  /// Opens the bus at `url` (empty: ResolveLcmUrl("")) with the bus key `key_file` (empty:
  /// ResolveBusKeyFile's choice), or none when `open_bus`; `process` and `name` as the messages
  /// say them. Throws FeedError naming the URL or key file if it cannot.
  LearnerPublisher(const std::string& url, const std::string& key_file, bool open_bus,
                   const std::string& process, const std::string& name);
  /// Closes as stopped (run state 2) unless Close said otherwise.
  ~LearnerPublisher();
  LearnerPublisher(const LearnerPublisher&) = delete;
  LearnerPublisher& operator=(const LearnerPublisher&) = delete;

  /// Keeps `report` as the learner's latest; the thread publishes it within a second.
  void Report(const LearnerReport& report);
  /// Publishes the latest report at once, three times, with the run state (1 ended, 2 stopped),
  /// and stops the thread. Later calls do nothing.
  void Close(bool ended);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen::feed
