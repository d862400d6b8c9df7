#pragma once

// What every consumer of scenes (the dataset writers, the Python stream, stackgen-view) does the
// same way, in one place: the consumer session of docs/design.md ("Processes, nodes and time"),
// which owns the bus, the delivery client, the bad-copy policy, the repeat check, the bus key check
// and the status each consumer publishes on STACKGEN_STATUS. The consumers keep only their own job:
// checking a scene for what they need and storing, queueing or drawing it.

#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/clock.h"
#include "session/delivery.h"

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
  /// Where its run stands (status.run_state, bus/channels.h): kRunRunning, or as it leaves
  /// kRunEnded (it took what it was asked for, or its stream ended) or kRunStopped (a signal,
  /// a timeout: before its end).
  int8_t run_state = 0;
};

/// How a consumer takes part, beyond its bus.
struct ConsumerSessionOptions {
  /// The program ("stackgen-coco", "stackgen-bop", "stackgen-feed", "stackgen-view") and the
  /// consumer's name, unique on the bus, as its status says them.
  std::string process;
  std::string name;
  /// A reliable consumer: a delivery client (credits, resends) with these options, its name set
  /// from `name`. Only on a live bus: a log (file://) takes no credits, and the session is then
  /// best effort.
  bool reliable = false;
  SceneClientOptions client;
  /// The channels the generators publish on, for the bus key check (Bus::KeyMismatch); empty:
  /// STACKGEN_SCENE and STACKGEN_CONFIG.
  std::vector<std::string> generator_channels;
  /// On a live bus Service says once on stderr (as `process`) that the generators heard use
  /// another bus key (or none) once that has been so for this long (seconds), and goes on
  /// waiting: nothing it cannot verify stops it (a stranger can send anything). An open
  /// consumer, which verifies nothing, stops then with that line (an exception from Service),
  /// and a log that ends so stops any (CheckKeys). It looks at a reliable or keyed consumer, or any
  /// with `strict_keys` (a dataset writer: an open one cannot take what keyed generators publish
  /// either; an open best-effort stream or viewer reads signed scenes all the same).
  double key_mismatch_s = 2.0;
  bool strict_keys = false;
  /// A live session publishes its status this often (seconds) and when it leaves; 0: only when
  /// asked (PublishStatus).
  double status_period_s = 1.0;
  /// Best effort: a scene is a repeat when one of the last `recent_scenes` had its ids.
  size_t recent_scenes = 4096;
  /// The clock of the status period; null: SteadyClock(). Must outlive the session.
  Clock* clock = nullptr;
};

/// One consumer's bus life: the bus, the delivery client of a reliable consumer, the bad-copy
/// policy (BadCopies), repeats of a best-effort one, the bus key check and the status. The
/// consumer subscribes its handlers (SubscribeScenes), tells the session what each copy was
/// (Fresh, Refuse, Stored, Skipped) and calls Service once per turn of its loop. Not
/// thread-safe: one thread (the one handling the bus) calls it.
class ConsumerSession {
 public:
  /// Takes the bus. Throws std::invalid_argument on client options out of range.
  ConsumerSession(std::unique_ptr<Bus> bus, ConsumerSessionOptions options);
  ~ConsumerSession();
  ConsumerSession(const ConsumerSession&) = delete;
  ConsumerSession& operator=(const ConsumerSession&) = delete;

  Bus& bus() { return *bus_; }
  const Bus& bus() const { return *bus_; }
  /// Whether the session credits scenes (a reliable consumer on a live bus: it has a delivery
  /// client); best effort otherwise.
  bool reliable() const { return client_ != nullptr; }
  /// Whether the bus is live (not a log being read).
  bool live() const { return live_; }
  const ConsumerSessionOptions& options() const { return options_; }

  /// Subscribes `handler` to the scenes on `channel` until the returned Subscription is
  /// dropped; a message that does not decode is counted (a bad message) and its text passed to
  /// `on_undecodable`.
  Subscription SubscribeScenes(const std::string& channel,
                               std::function<void(const scene&)> handler, int queue_capacity,
                               std::function<void(const std::string&)> on_undecodable);
  /// Once the consumer has subscribed: hears the generator channels it did not subscribe to
  /// for the bus key check (a generator announces its config before its first scene).
  void WatchGeneratorKeys();

  /// A copy of (generator_id, seq) that passed the consumer's checks arrived. True when it is
  /// new: a reliable client's Received (Stored or Skipped must follow), or, best effort, none of
  /// the last recent_scenes had its ids; false for a repeat (counted).
  bool Fresh(int32_t generator_id, int64_t seq);
  /// A copy of (generator_id, seq) failed the consumer's checks (counted as a bad message). It
  /// tells a reliable client nothing, so a stranger's or a damaged copy cannot take the real
  /// scene's place: that seq is asked for again, and given up (Received, Skipped) after
  /// BadCopies::kCopies bad copies of it, unless a good copy came (Fresh) before.
  void Refuse(int32_t generator_id, int64_t seq);
  /// The scene Fresh said was new is stored (handed out, drawn) or will never be.
  void Stored(int32_t generator_id, int64_t seq);
  void Skipped(int32_t generator_id, int64_t seq);
  /// A good copy of a scene the consumer does not take (another shard's): it still shows a
  /// reliable client how far the generator has got. Nothing best effort.
  void Passed(int32_t generator_id, int64_t seq);
  /// Seqs of `generator_id` stored by an earlier run of this consumer (--resume), and the run
  /// (RunName) whose scenes of it the consumer holds, which its credits carry (a generator of
  /// another run refuses to continue it): for a reliable session (SceneClient::Restore,
  /// SetRun); nothing best effort.
  void Restore(int32_t generator_id, const std::vector<int64_t>& seqs);
  void SetRun(int32_t generator_id, const std::string& run);
  /// Sends the credits and resend requests that are due now (what Service does first), without
  /// the key check or the status: after storing, between turns. Nothing best effort.
  void Credit();
  /// The highest seq s of `generator_id` such that 0..s are all stored or skipped; -1 if none,
  /// and always best effort.
  int64_t StoredThrough(int32_t generator_id) const;
  /// A repeat the consumer found itself (a best-effort writer's dataset held it already).
  void CountRepeat() { ++repeats_; }
  /// A copy refused for what it is not (another run's scene): counted, nothing more.
  void CountRefused() { ++refused_; }

  /// Throws std::runtime_error with Bus::KeyMismatch's line when the generators heard use
  /// another bus key (at the end of a log; see key_mismatch_s).
  void CheckKeys() const;
  /// Bus::KeyMismatch's line now (see key_mismatch_s), "" when there is none: what a consumer
  /// that ends for a reason of its own (a timeout) adds to its message.
  std::string KeyHint() const;
  /// Once per turn of the consumer's loop: the client's credits and resends, the bus key
  /// warning and, when due, the status. `held`: the scenes the consumer holds (stored, handed out,
  /// drawn); `taken`: those it took in this run.
  void Service(int64_t held, int64_t taken);
  /// Publishes the status now (see Service), with `run_state` (status.run_state: kRunRunning,
  /// or kRunEnded or kRunStopped as the consumer leaves).
  void PublishStatus(int64_t held, int64_t taken, int8_t run_state);
  /// The last status (unless status_period_s is 0), saying how the run ended: kRunEnded (the
  /// consumer took what it was asked for, or its stream ended) or kRunStopped (a signal, a
  /// timeout), so a monitor shows it ended, not gone quiet; and a reliable client's leaving
  /// credit: generators stop waiting for it. Nothing on a log.
  void Leave(int64_t held, int64_t taken, int8_t run_state);

  /// What did not make it: messages that did not decode, copies refused, repeats.
  int64_t undecodable() const { return undecodable_; }
  int64_t refused() const { return refused_; }
  int64_t repeats() const { return repeats_; }
  /// Scenes that reached the handlers of SubscribeScenes (decoded; good or not, repeats too).
  int64_t received() const { return received_; }
  /// The client's counters (a best-effort session: received and repeats only).
  DeliveryCounters delivery() const;

 private:
  ConsumerSessionOptions options_;
  std::unique_ptr<Bus> bus_;
  bool live_ = false;
  bool keys_said_ = false;  // the bus key warning, until a message of this key is heard
  std::unique_ptr<SceneClient> client_;
  Clock* clock_;
  BadCopies bad_copies_;
  std::set<std::pair<int32_t, int64_t>> recent_;
  std::deque<std::pair<int32_t, int64_t>> recent_order_;
  int64_t undecodable_ = 0;
  int64_t refused_ = 0;
  int64_t repeats_ = 0;
  int64_t received_ = 0;
  Clock::TimePoint last_status_;
  int64_t held_at_last_status_ = -1;  // -1: none seen yet (the first Service sets it)
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
