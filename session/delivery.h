#pragma once

// Delivery without loss (docs/design.md, "Delivery without loss"): the small protocol the bus
// layers on typed messages so that dataset writers lose no scene while a live viewer never slows
// the generator.
//
// - A reliable consumer (SceneClient) registers by sending credits on STACKGEN_CREDIT: per
//   generator, the last seq below which it has durably stored every scene, the highest seq it
//   received and how many more scenes it can take (its window).
// - The generator (SceneServer) never publishes a seq above stored + window of any registered
//   consumer; a consumer silent for longer than a timeout is dropped from the set with a warning.
// - A consumer that sees a gap asks for the missing seqs on STACKGEN_RESEND (and asks again while
//   they stay missing); the generator serves them from a ring of recent scenes, or beyond it
//   regenerates them from the seed (determinism makes them exact). A tail the consumer never saw
//   (no later scene shows the gap) is resent by the generator when the consumer's credit says it
//   has not received it a short while after publication.
// - Best-effort consumers send nothing and are never waited for.

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "bus/bus.h"
#include "bus/clock.h"

namespace stackgen {

/// What names a generator's run in credits and datasets, so that a dataset is never continued by
/// another run: "seed S, config PATH (sha256 HEX)", HEX the first 16 hex digits of the SHA-256
/// of the effective config text (OpenSSL). Throws std::runtime_error if OpenSSL cannot hash.
std::string RunName(int64_t base_seed, const std::string& config_path,
                    const std::string& config_pbtxt);

/// True when two RunNames name the same run: the same seed and config contents (the paths may
/// differ: the same config on another host). Text that is not a RunName equals only itself.
bool SameRun(const std::string& a, const std::string& b);

/// How a SceneServer serves its consumers.
struct SceneServerOptions {
  /// The generator's id (header.generator_id of its scenes).
  int32_t generator_id = 0;
  /// Encoded scenes kept for resending, most recent ones (default 64).
  int ring_size = 64;
  /// A registered consumer with no credit for this long is dropped from the set, with a warning
  /// (seconds, default 10).
  double consumer_timeout_s = 10;
  /// A consumer whose credit says it has not received the newest scenes this long after they
  /// were published, and this long after it last received one, gets them again (seconds,
  /// default 0.3). Each such resend after which it received nothing doubles the wait for the
  /// next (up to 5 s), and a consumer not heard for 1 s (paused, stopped) gets none.
  double tail_resend_s = 0.3;
  /// A seq resent less than this ago is not resent again for another request (seconds,
  /// default 0.1), so that several consumers asking for it at once cost one resend.
  double min_resend_interval_s = 0.1;
  /// A registered consumer that still credits but has received nothing of what it lacks and can
  /// take, while it was sent again, for this long cannot be served over this bus (it loses every
  /// copy): stalled() says so and the generator stops instead of waiting for ever (seconds,
  /// default 60).
  double stall_timeout_s = 60;
  /// This generator's RunName; empty: not checked. A credit naming another run (a consumer that
  /// holds scenes of another seed or config) registers nothing and sets run_conflict().
  std::string run;
  /// The clock every timeout above is measured on; null: SteadyClock(). Must outlive the server.
  Clock* clock = nullptr;
};

/// The generator's side: publishes scenes on STACKGEN_SCENE, keeps the recent ones, follows
/// the credits of reliable consumers and serves resend requests. Subscribes to STACKGEN_CREDIT
/// and STACKGEN_RESEND on the bus given; messages there that address another generator are
/// skipped; those that do not decode or that no SceneClient sends are counted (bad_messages) and
/// skipped, the first of each kind said in a notice: a credit with an empty or over-long name,
/// seqs outside -1..99999998 or a window outside 0..10000; a resend request for more than 256
/// seqs, for seqs not ascending or never published. A consumer that offers no window (0) for
/// longer than the consumer timeout is no longer waited for until it offers one. Resend
/// requests are served only for seqs the consumer has not stored and can take (its window). Not
/// thread-safe.
class SceneServer {
 public:
  /// Returns the encoded scene `seq` made again (for a seq older than the ring).
  using Regenerate = std::function<std::vector<uint8_t>(int64_t seq)>;
  /// Receives one line about consumers registering, leaving or going silent.
  using Notice = std::function<void(const std::string&)>;

  /// `bus` must outlive the server; its subscriptions end with it (the bus may go on handling
  /// messages). Throws std::invalid_argument on options out of range.
  SceneServer(Bus* bus, const SceneServerOptions& options, Regenerate regenerate, Notice notice);
  ~SceneServer();
  SceneServer(const SceneServer&) = delete;
  SceneServer& operator=(const SceneServer&) = delete;

  /// Publishes the encoded scene `seq` on STACKGEN_SCENE for the first time and keeps it in the
  /// ring. Seqs must increase by one from the first one published.
  void Publish(int64_t seq, std::vector<uint8_t> encoded_scene);

  /// True when publishing `seq` keeps within the window of every registered consumer (always
  /// true with none registered).
  bool MayPublish(int64_t seq) const;

  /// Handles credits and resend requests that arrive within `timeout_ms`, then drops consumers
  /// silent for longer than the timeout, and serves what is due: requested seqs and unreceived
  /// tails (published again from the ring or regenerated). Throws what the bus or Regenerate
  /// throws.
  void Service(int timeout_ms);

  /// True when every registered consumer has stored every seq up to `last_seq` (or has left).
  bool AllStoredThrough(int64_t last_seq) const;

  /// The seq to continue at after a restart: the smallest "stored through + 1" of the registered
  /// consumers; unset while none is registered.
  std::optional<int64_t> ResumeSeq() const;

  /// Reliable consumers registered now.
  int reliable_consumers() const;
  /// Reliable consumers ever registered (a consumer registering again counts again).
  int64_t registrations() const;
  /// The consumers dropped for going silent (consumer timeout) that have not registered again
  /// since, by name: their datasets may lack scenes.
  std::vector<std::string> gone_silent() const;
  /// Scenes published again from the ring.
  int64_t resent() const;
  /// Scenes regenerated (older than the ring) and published again.
  int64_t regenerated() const;
  /// Credit and resend messages that did not decode or were refused.
  int64_t bad_messages() const;
  /// Empty, or one line naming the first consumer whose credit named another run than
  /// options.run, and both runs: the generator must not go on for it.
  const std::string& run_conflict() const;
  /// Empty, or one line naming a consumer that has received nothing it lacks for
  /// stall_timeout_s though it still credits and was sent its scenes again, and what it lacks:
  /// the run cannot progress.
  std::string stalled() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// How a SceneClient takes part in delivery.
struct SceneClientOptions {
  /// The consumer's name in its credits, unique on the bus and stable across restarts of the
  /// same writer (e.g. "stackgen-coco@host:/data/set1").
  std::string name;
  /// Scenes it can take beyond what it has stored, per generator (default 8, >= 1).
  int32_t window = 8;
  /// Scenes it wants in all (restored ones included), 0 = no limit. The window shrinks so that
  /// a generator never publishes more than the consumer will store; skipped scenes do not count.
  int64_t max_scenes = 0;
  /// Credits are sent this often when nothing changes (seconds, default 0.2).
  double credit_period_s = 0.2;
  /// A missing seq is asked for again after this long (seconds, default 0.3).
  double reask_after_s = 0.3;
  /// The generators it takes scenes from; empty (the default): every generator. With a list,
  /// credits go to those generators from the start and no wildcard credit is sent, so other
  /// generators never wait for this consumer; their scenes are not tracked (Received: false).
  std::vector<int32_t> generator_ids;
  /// Consumers that split one stream between them (the DataLoader workers of one learner) each
  /// take one shard: the seqs with seq % shard_count == shard_index, of every generator. The
  /// seqs of other shards count as done (never asked for, never waited for, not counted), so a
  /// generator is held back only by what this consumer's own shard still lacks.
  /// shard_count 1..kMaxShards (default 1: every seq), shard_index 0..shard_count-1.
  int32_t shard_index = 0;
  int32_t shard_count = 1;
  /// False (a dataset writer): every generator is taken from seq 0, and a wildcard credit
  /// registers the consumer with generators it has not heard from. True (a learner): a generator
  /// is credited only once a scene of it has been heard, and one first heard past seq `window`
  /// is taken from that seq on (earlier seqs count as done), so a learner that joins a running
  /// generator never makes it resend its history; one first heard at a lower seq started with
  /// the learner and is taken from seq 0.
  bool join_where_heard = false;
  /// The first seq it takes of every generator (0..99999998, default 0): lower seqs count as
  /// done (never asked for, never waited for, not counted), and the wildcard credit says so, so
  /// a generator started at this seq (stackgen --first-seq) is not held back by the seqs before
  /// it. One task of a cluster job stores seqs first_seq .. first_seq + max_scenes - 1.
  int64_t first_seq = 0;
  /// The clock the credit period and the re-asking are measured on; null: SteadyClock(). Must
  /// outlive the client.
  Clock* clock = nullptr;
};

/// The most consumers one stream can be split between (SceneClientOptions::shard_count).
inline constexpr int32_t kMaxShards = 256;

/// Counters of a SceneClient since it started (see status.lcm).
struct DeliveryCounters {
  /// Scenes received, duplicates included.
  int64_t received = 0;
  /// Scenes stored.
  int64_t stored = 0;
  /// Scenes received again after they were stored or skipped.
  int64_t duplicates = 0;
  /// Seqs missing now, below the highest seq received of each generator.
  int64_t lost = 0;
  /// Seqs asked for on STACKGEN_RESEND, each ask counted.
  int64_t reasked = 0;
};

/// A reliable consumer's side: tracks, per generator, what it received and stored, sends
/// credits and resend requests. The consumer subscribes to STACKGEN_SCENE itself and tells the
/// client about every scene (Received, then Stored or Skipped). Not thread-safe.
class SceneClient {
 public:
  /// `bus` must outlive the client. Throws std::invalid_argument on options out of range.
  /// Generator ids outside 0..65535 (or outside options.generator_ids) and seqs outside
  /// 0..99999998 are not tracked: Received returns false for them, and Stored, Skipped and
  /// Restore ignore them. So are seqs of other shards, except that Received notes them as
  /// published (they show that a generator has gone on, and count as done).
  SceneClient(Bus* bus, const SceneClientOptions& options);
  ~SceneClient();
  SceneClient(const SceneClient&) = delete;
  SceneClient& operator=(const SceneClient&) = delete;

  /// Seqs stored by an earlier run of the same consumer (--resume); not counted as received.
  void Restore(int32_t generator_id, const std::vector<int64_t>& seqs);

  /// The RunName of the run whose scenes of `generator_id` the consumer holds (from its
  /// dataset, or the generator's STACKGEN_CONFIG): its credits to that generator carry it, so a
  /// generator of another run refuses to continue the dataset. Ignored for ids not tracked.
  void SetRun(int32_t generator_id, const std::string& run);

  /// Scene `seq` of `generator_id` arrived. True when it is new and should be stored: it is then
  /// pending (never asked for again) until Stored or Skipped, which must follow. False when it
  /// was stored or skipped before, or is pending (counted as a duplicate), or its ids are out of
  /// range.
  bool Received(int32_t generator_id, int64_t seq);
  /// The scene Received said was new is now durably stored.
  void Stored(int32_t generator_id, int64_t seq);
  /// The scene Received said was new will never be stored (e.g. invalid): stop asking for it.
  void Skipped(int32_t generator_id, int64_t seq);

  /// Sends what is due: credits (every credit period, and at once when something was stored)
  /// and resend requests for missing seqs. Cheap when nothing is due; call it often.
  void Service();
  /// Sends a last credit, marked leaving, for every generator (and the wildcard).
  void Leave();

  /// The highest seq s of `generator_id` such that 0..s are all stored or skipped; -1 if none.
  int64_t StoredThrough(int32_t generator_id) const;
  /// Counters since start; `lost` is the number of seqs missing right now.
  DeliveryCounters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
