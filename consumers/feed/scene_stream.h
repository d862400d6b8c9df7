#pragma once

// The learner's end of the bus: a stream of checked scenes for a training process, the core of
// the Python package `stackgen` (consumers/feed/python_module.cc binds it).
//
// A thread of its own reads the bus (or an LCM log), checks and decodes every scene and queues it;
// the learner takes scenes from the queue. On a live bus a reliable stream is a reliable consumer
// (session/delivery.h): it credits each scene once it has been handed to the learner and asks for
// what it missed, so it loses nothing and holds the generators within its window; a best-effort
// stream sends nothing, keeps only the newest scenes when the learner falls behind and never holds
// a generator back. Because the thread serves the bus, credits flow while the learner trains.

#include <sys/types.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "bus/clock.h"
#include "consumers/feed/scene_data.h"

namespace stackgen::feed {

/// No scene arrived within the time the learner would wait.
class FeedTimeout : public FeedError {
 public:
  using FeedError::FeedError;
};

/// What a SceneStream reads and how.
struct SceneStreamOptions {
  /// The bus (udpm://, memq://) or an LCM log (file://PATH; a query such as ?speed=0 is
  /// ignored: a log is read in order, as fast as scenes are taken). Empty: ResolveLcmUrl("").
  std::string url;
  /// The channel of the scenes.
  std::string channel = "STACKGEN_SCENE";
  /// Live bus only: a reliable consumer (credits, resend) or best effort (sends nothing).
  bool reliable = true;
  /// Reliable: scenes a generator may run ahead of what was handed out, per generator, >= 1.
  int32_t window = 8;
  /// The generators to take scenes from; empty: all.
  std::vector<int32_t> generator_ids;
  /// This stream takes the seqs with seq % shard_count == shard_index (of every generator).
  int32_t shard_index = 0;
  int32_t shard_count = 1;
  /// Scenes to hand out in all, then the stream ends; 0: no end (a log ends at its end).
  int64_t count = 0;
  /// Scenes kept waiting for the learner: best effort drops the oldest beyond this; a log waits.
  /// (A reliable live stream keeps what its window lets in.) >= 1.
  int queue = 16;
  /// A log: hand out every event, repeats too, counting FeedScene::occurrence (a recording made
  /// by StreamDataset, which repeats a scene for each use). False: each scene once.
  bool repeats = false;
  /// Decode these images ahead, in the stream's decoder threads, while the scene waits in the
  /// queue (the others are decoded when first asked for).
  bool decode_color = true;
  bool decode_depth = false;
  bool decode_instance_map = true;
  /// Threads that decode images ahead, 1..16 (default 2): PNG decoding is most of a scene's
  /// cost, and scenes decode side by side; they are handed out in their order all the same.
  int decode_threads = 2;
  /// The consumer's name in credits and status; empty: "stackgen-feed@<host>:<pid>[/shard i/k]".
  std::string name;
  /// The bus key file (bus/auth.h); empty: $STACKGEN_BUS_KEY_FILE when set, else this user's
  /// key (made on first use). A log is checked with it too (it replays with the key it was
  /// recorded under).
  std::string bus_key_file;
  /// No key at all: every sender trusted, nothing signed (an open bus, or a log recorded on one).
  bool open_bus = false;
  /// Live bus: the scenes come from a recording played back onto the bus (lcm-logplayer): taken
  /// without the liveness check of the bus key, which refuses recordings by default.
  bool replay = false;
  /// Drop this fraction of received messages on purpose, [0, 1) (tests and demos).
  double fault_drop = 0;
  /// Live bus: publish the stream's counters on STACKGEN_STATUS every second.
  bool publish_status = true;
  /// The time the stream reads for its waits, messages and the generators' end (bus/clock.h);
  /// null: SteadyClock(). Must outlive the stream. (A wait itself sleeps in slices of 0.1 s.)
  Clock* clock = nullptr;
};

/// Counters of a stream since it opened.
struct StreamCounters {
  /// Scene messages of this stream's generators and shard that arrived, repeats included.
  int64_t received = 0;
  /// Scenes handed to the learner.
  int64_t handed = 0;
  /// Scenes that arrived again (resent for another consumer, or twice in a log), handed once.
  int64_t duplicates = 0;
  /// Reliable: seqs missing now below the highest received; asked for again on STACKGEN_RESEND.
  int64_t lost = 0;
  int64_t reasked = 0;
  /// Messages that did not decode or scenes that failed CheckFeedScene, skipped.
  int64_t bad_messages = 0;
  /// Best effort: scenes dropped because the learner was behind (the queue was full).
  int64_t dropped_behind = 0;
  /// Messages the bus dropped on purpose (fault_drop).
  int64_t fault_dropped = 0;
  /// Messages refused by the bus key check (see bus/auth.h): not signed, forged or altered,
  /// replayed. On a log: events refused the same way (no replay by age).
  int64_t refused_unsigned = 0;
  int64_t refused_forged = 0;
  int64_t refused_replayed = 0;
  int64_t refused_relayed = 0;
  /// Scenes waiting in the queue now.
  int64_t queued = 0;
};

/// A stream of scenes from the bus or a log. Next and Close may be called from any one thread
/// at a time; the stream's own thread does everything else.
class SceneStream {
 public:
  /// Opens the bus (throwing FeedError with the URL and reason if it cannot: a bad URL, no
  /// multicast route) or checks the log (FeedError if it is missing, a folder or not an LCM
  /// log), then starts reading. Throws FeedError on options out of range. The stream fails
  /// (Next throws FeedError, one line) when the generators heard for 2 s all use another bus
  /// key (or none), and when every scene of a log was refused for its key.
  explicit SceneStream(const SceneStreamOptions& options);
  /// Close().
  ~SceneStream();
  SceneStream(const SceneStream&) = delete;
  SceneStream& operator=(const SceneStream&) = delete;

  /// The next scene, waiting up to `timeout_s` seconds (< 0: as long as it takes); nullptr once
  /// the stream has ended (count scenes handed out, the end of a log, Close, or on a live bus
  /// every generator heard has said in its status that its run ended or stopped, 0.5 s ago;
  /// the stream then prints a line saying so). A wait of 2 s prints what the stream waits for
  /// (no generator heard yet, or when each was last heard), again every 30 s. `interrupted` is
  /// called about every 100 ms while waiting and stops the wait when it returns true (nullptr
  /// then). Throws FeedTimeout when the time ran out, FeedError when the stream failed (the bus,
  /// a log event that is not a scene of this build, a log without scenes), and FeedError when
  /// called from another process than the one that opened the stream (a stream cannot be shared
  /// between DataLoader workers: each opens its own).
  std::shared_ptr<FeedScene> Next(double timeout_s, const std::function<bool()>& interrupted);

  /// Stops the thread; a reliable stream sends its last credits (leaving), so generators stop
  /// waiting for it at once. Idempotent.
  void Close();

  StreamCounters counters() const;
  /// The URL in use (the default resolved) and the consumer's name.
  const std::string& url() const;
  const std::string& name() const;
  /// Whether this is a log rather than a live bus.
  bool is_log() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The path of a file:// URL (the part between "file://" and any '?'); empty for other URLs.
std::string LogPathOfUrl(const std::string& url);

}  // namespace stackgen::feed
