#pragma once

// What every consumer of scenes (the dataset writers, the Python stream, stackgen-view) does the
// same way, in one place: the bad-copy policy of a reliable consumer and the status message each
// publishes on STACKGEN_STATUS. (The first pieces of the consumer session of design.md,
// "Processes, nodes and time".)

#include <cstdint>
#include <map>
#include <string>
#include <utility>

#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/delivery.h"

namespace stackgen {

/// A reliable consumer's rule for copies of a scene that fail its checks: a bad copy tells the
/// delivery client nothing (a stranger's or a damaged copy cannot take the real scene's place:
/// the seq is asked for again); a seq whose copies keep failing (a generator that publishes a
/// bad scene, resends included) is given up after kCopies of them. Remembers at most kMaxSeqs
/// seqs (a flood of bad copies of ever new seqs starts it afresh).
class BadCopies {
 public:
  static constexpr int kCopies = 3;
  static constexpr size_t kMaxSeqs = 4096;

  /// A copy of (generator_id, seq) failed the checks. True when that seq is now given up: the
  /// consumer tells its client (Received, then Skipped) and the count starts again.
  bool Note(int32_t generator_id, int64_t seq) {
    if (counts_.size() >= kMaxSeqs) counts_.clear();
    const std::pair<int32_t, int64_t> key{generator_id, seq};
    if (++counts_[key] < kCopies) return false;
    counts_.erase(key);
    return true;
  }
  /// A good copy of (generator_id, seq) arrived: its bad ones are forgotten.
  void Forget(int32_t generator_id, int64_t seq) { counts_.erase({generator_id, seq}); }
  /// Seqs with bad copies remembered now.
  size_t size() const { return counts_.size(); }

 private:
  std::map<std::pair<int32_t, int64_t>, int> counts_;
};

/// What a consumer says of itself in its status (status.lcm).
struct ConsumerReport {
  /// The program: "stackgen-coco", "stackgen-bop", "stackgen-feed", "stackgen-view".
  std::string process;
  /// Unique on the bus (a reliable consumer's credit name).
  std::string name;
  /// Scenes it holds: stored in its dataset, handed to its learner, drawn on its sheet.
  int64_t scenes_held = 0;
  /// Scenes it took in this run.
  int64_t scenes = 0;
  /// Scenes per second since its last status.
  double rate_hz = 0;
  /// Its delivery client's counters (a best-effort consumer: received and duplicates only).
  DeliveryCounters delivery;
  /// Messages it could not use: undecodable, or scenes that failed its checks.
  int64_t bad_messages = 0;
};

/// A consumer's bus options from its flags: --fault-drop F (that share of what it receives
/// dropped on purpose, drawn from `fault_seed`), --bus-key-file, --open-bus, --replay.
BusOptions ConsumerBusOptions(double fault_drop, const std::string& key_file, bool open_bus,
                              bool replay, uint64_t fault_seed);

/// Makes SIGINT and SIGTERM call `handler` (which should only set a flag the consumer's loop
/// reads), with system calls restarted after it.
void StopOnSignals(void (*handler)(int));

/// The status message of a consumer: no generator id or seq (-1), the report, and the bus's
/// counters of messages dropped on purpose (--fault-drop) and refused by the bus key. The
/// caller sets header.utime (or leaves UnixMicros' now, the default here).
status ConsumerStatus(const Bus& bus, const ConsumerReport& report);

}  // namespace stackgen
