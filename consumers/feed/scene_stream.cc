#include "consumers/feed/scene_stream.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>
#include <utility>

#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/log.h"
#include "contract/bounded_decode.h"
#include "contract/scene_contract.h"
#include "session/consumer.h"
#include "session/delivery.h"

namespace stackgen::feed {
namespace {

using SceneKey = std::pair<int32_t, int64_t>;  // generator_id, seq

// problems reported one by one on stderr; later ones are only counted
constexpr int kMaxReported = 10;
// generators heard for this long that all use another bus key are said on a live stream
// (seconds); a timeout names them
constexpr double kKeyMismatchS = 2.0;
// best effort: scene keys remembered to recognise a repeat (a resend for a reliable consumer)
constexpr size_t kRecentKeys = 4096;
// the most scenes a queue may hold
constexpr int kMaxQueue = 100000;
// a live stream ends this long after every generator it takes from said its run ended or
// stopped (seconds): a best-effort stream's last scenes are still on their way
constexpr double kEndGraceS = 0.5;
// a learner waiting this long for a scene is told what the stream waits for, and again at each
// kSayAgainS (seconds)
constexpr double kSayWaitingS = 2.0;
constexpr double kSayAgainS = 30.0;
// the most generators a stream keeps news of (a stranger could vary ids without end)
constexpr size_t kMaxGeneratorsHeard = 256;

// thrown inside the log reader to stop reading
struct StopReading {};

// the big-endian unsigned number in `size` bytes at `bytes`
uint64_t ReadBigEndian(const uint8_t* bytes, int size) {
  uint64_t value = 0;
  for (int k = 0; k < size; ++k) value = (value << 8) | bytes[k];
  return value;
}

std::string DefaultName(const SceneStreamOptions& options) {
  char host[256] = "localhost";
  gethostname(host, sizeof(host) - 1);
  std::string name = "stackgen-feed@" + std::string(host) + ":" + std::to_string(getpid());
  if (options.shard_count > 1) {
    name +=
        "/shard" + std::to_string(options.shard_index) + "of" + std::to_string(options.shard_count);
  }
  return name;
}

}  // namespace

std::string LogPathOfUrl(const std::string& url) {
  const std::string scheme = "file://";
  if (url.rfind(scheme, 0) != 0) return "";
  const std::string rest = url.substr(scheme.size());
  return rest.substr(0, rest.find('?'));
}

struct SceneStream::Impl {
  SceneStreamOptions options;
  std::string url;
  std::string name;
  std::string log_path;                   // empty: a live bus
  std::unique_ptr<MessageAuth> log_auth;  // a log's events are checked with the bus key
  pid_t pid = 0;

  // live: the consumer session (the bus and, when reliable, the delivery client); used by the
  // thread only
  std::unique_ptr<ConsumerSession> session;
  bool reliable = false;  // a live reliable stream: handed and skipped scenes are credited
  std::thread thread;
  std::atomic<bool> stop{false};

  // shared between the thread and Next, under `mutex`
  mutable std::mutex mutex;
  std::condition_variable changed;
  std::deque<std::shared_ptr<FeedScene>> queue;
  // reliable: scenes queued or handed out but not yet marked stored in the client, which would
  // still take a resent copy of them for new
  std::set<SceneKey> taken_keys;
  std::vector<SceneKey> handed_pending;   // handed out, not yet credited
  std::vector<SceneKey> skipped_pending;  // did not decode, not yet told to the client
  // scenes queued whose images the decoder threads are to decode, oldest first
  std::deque<std::shared_ptr<FeedScene>> to_decode;
  std::condition_variable decode_wanted;
  std::vector<std::thread> decoders;
  bool decoders_stop = false;
  StreamCounters counters;
  std::exception_ptr error;
  bool ended = false;
  bool closed = false;
  // live: the generators heard (their scenes or status), and how their runs stand
  struct Generator {
    std::string name;
    int8_t run_state = kRunRunning;
    int64_t scenes = 0;  // published, as their status says
    Clock::TimePoint heard;
  };
  std::map<int32_t, Generator> generators;
  // the time the stream reads (bus/clock.h: options.clock, else the steady clock)
  Clock* clock = &SteadyClock();
  Clock::TimePoint opened;
  Clock::TimePoint last_said;  // a waiting learner was last told what the stream waits for
  bool said_waiting = false;

  // thread-only state
  std::atomic<int> reported{0};

  // a generator this stream takes scenes from (options.generator_ids, or all)
  bool WantedGenerator(int32_t generator_id) const {
    const std::vector<int32_t>& ids = options.generator_ids;
    return ids.empty() || std::find(ids.begin(), ids.end(), generator_id) != ids.end();
  }

  bool Wanted(int32_t generator_id, int64_t seq) const {
    return WantedGenerator(generator_id) && seq % options.shard_count == options.shard_index;
  }

  void Report(const std::string& text) {
    if (++reported <= kMaxReported) {
      std::fprintf(stderr, "stackgen-feed: skipped a scene: %s%s\n", text.c_str(),
                   reported == kMaxReported ? " (later ones are only counted)" : "");
    }
  }

  void CountBad() {
    const std::lock_guard<std::mutex> lock(mutex);
    ++counters.bad_messages;
  }

  // whether a scene passes CheckFeedScene; one that does not is counted and reported
  bool Check(const scene& message) {
    std::string why;
    if (CheckFeedScene(message, &why)) return true;
    CountBad();
    Report("scene " + std::to_string(message.header.generator_id) + "/" +
           std::to_string(message.header.seq) + ": " + why);
    return false;
  }

  // a checked scene, its images to be decoded ahead by the decoder threads
  std::shared_ptr<FeedScene> Prepare(scene message) {
    auto prepared = std::make_shared<FeedScene>(std::move(message));
    if (options.decode_color || options.decode_instance_map || options.decode_depth) {
      {
        const std::lock_guard<std::mutex> lock(mutex);
        to_decode.push_back(prepared);
      }
      decode_wanted.notify_one();
    } else {
      prepared->Prepare(false, false, false);
    }
    return prepared;
  }

  // a decoder thread: decodes the images of queued scenes, oldest first
  void RunDecoder() {
    while (true) {
      std::shared_ptr<FeedScene> next;
      {
        std::unique_lock<std::mutex> lock(mutex);
        decode_wanted.wait(lock, [this] { return decoders_stop || !to_decode.empty(); });
        if (decoders_stop) return;
        next = std::move(to_decode.front());
        to_decode.pop_front();
      }
      next->Prepare(options.decode_color, options.decode_depth, options.decode_instance_map);
    }
  }

  // a scene from the live bus (the thread, inside HandleFor)
  void OnLiveScene(const scene& message) {
    const int32_t generator_id = message.header.generator_id;
    const int64_t seq = message.header.seq;
    if (!SceneIdsInRange(generator_id, seq)) {
      CountBad();
      session->CountRefused();
      Report("scene " + std::to_string(generator_id) + "/" + std::to_string(seq) +
             ": generator_id or seq out of range");
      return;
    }
    const bool wanted = Wanted(generator_id, seq);
    if (!wanted) {
      // another shard's scene still shows the client how far the generator has got, when it
      // is a scene (that shard counts and reports a bad one)
      std::string why;
      if (reliable && CheckFeedScene(message, &why)) session->Passed(generator_id, seq);
      return;
    }
    const SceneKey key{generator_id, seq};
    Heard(generator_id, nullptr);
    // a copy that fails the checks tells the client nothing (it neither sets where a learner
    // joins a generator nor marks its seq done): the session's bad-copy policy
    if (!Check(message)) {
      session->Refuse(generator_id, seq);
      return;
    }
    {
      const std::lock_guard<std::mutex> lock(mutex);
      ++counters.received;
      const bool enough = options.count > 0 &&
                          counters.handed + static_cast<int64_t>(queue.size()) >= options.count;
      if (enough) return;
    }
    // a repeat: the client's, a scene still queued or handed out, or (best effort) one of the
    // last scenes
    {
      bool repeat = !session->Fresh(generator_id, seq);
      const std::lock_guard<std::mutex> lock(mutex);
      repeat = repeat || taken_keys.count(key) != 0;
      if (repeat) {
        ++counters.duplicates;
        return;
      }
    }
    std::shared_ptr<FeedScene> prepared = Prepare(message);
    {
      const std::lock_guard<std::mutex> lock(mutex);
      // best effort keeps the newest scenes: the learner never holds a generator back
      if (!reliable && static_cast<int>(queue.size()) >= options.queue) {
        // (and its images need no decoding any more)
        const auto waiting = std::find(to_decode.begin(), to_decode.end(), queue.front());
        if (waiting != to_decode.end()) to_decode.erase(waiting);
        queue.pop_front();
        ++counters.dropped_behind;
      }
      queue.push_back(std::move(prepared));
      if (reliable) taken_keys.insert(key);
    }
    changed.notify_all();
  }

  // news of a generator this stream takes from: a scene (`news` null) or its status
  void Heard(int32_t generator_id, const status* news) {
    const std::lock_guard<std::mutex> lock(mutex);
    if (generators.count(generator_id) == 0 && generators.size() >= kMaxGeneratorsHeard) return;
    Generator& generator = generators[generator_id];
    generator.heard = clock->Now();
    // (a scene says nothing of the run: a resend may come after the last status; a generator
    // started again says so in its status)
    if (news == nullptr) return;
    generator.name = news->name;
    generator.run_state = news->run_state;
    generator.scenes = news->scenes;
  }

  void OnStatus(const status& message) {
    if (message.process != "stackgen" || !SceneIdsInRange(message.header.generator_id, 0) ||
        !WantedGenerator(message.header.generator_id)) {
      return;
    }
    Heard(message.header.generator_id, &message);
  }

  // the line that ends a live stream once every generator heard has ended or stopped for
  // kEndGraceS; "" while one still runs (or none was heard)
  std::string EndOfGenerators() const {
    const std::lock_guard<std::mutex> lock(mutex);
    if (generators.empty()) return "";
    std::string said;
    for (const auto& [generator_id, generator] : generators) {
      if (generator.run_state == kRunRunning ||
          std::chrono::duration<double>(clock->Now() - generator.heard).count() < kEndGraceS) {
        return "";
      }
      said += (said.empty() ? "" : ", ") + std::string("generator ") +
              std::to_string(generator_id) +
              (generator.run_state == kRunEnded ? " ended its run" : " stopped before its end") +
              " (" + std::to_string(generator.scenes) + " scenes published)";
    }
    return said + ": the stream ends after the " + std::to_string(counters.received) +
           " scenes it received";
  }

  // what a waiting learner waits for (under `mutex`)
  std::string WaitingFor() const {
    const auto now = clock->Now();
    if (generators.empty()) {
      return "no generator heard on " + url + " since the stream opened " +
             std::to_string(static_cast<int>(
                 std::chrono::duration<double>(now - opened).count() + 0.5)) +
             " s ago (is one publishing there, with this bus key?)";
    }
    std::string said;
    for (const auto& [generator_id, generator] : generators) {
      char ago[32];
      std::snprintf(ago, sizeof(ago), "%.1f",
                    std::chrono::duration<double>(now - generator.heard).count());
      said += (said.empty() ? "" : ", ") + std::string("generator ") +
              std::to_string(generator_id) + " last heard " + ago + " s ago";
    }
    return said + "; " + std::to_string(counters.handed) + " scenes handed out so far";
  }

  StreamCounters Counters() const {
    StreamCounters copy;
    {
      const std::lock_guard<std::mutex> lock(mutex);
      copy = counters;
      copy.queued = static_cast<int64_t>(queue.size());
    }
    return copy;
  }

  // the thread on a live bus: handle messages, credit what was handed out, publish status
  void RunLive() {
    Bus& bus = session->bus();
    const auto credit_handed = [&] {
      std::vector<SceneKey> handed;
      {
        const std::lock_guard<std::mutex> lock(mutex);
        handed.swap(handed_pending);
      }
      std::vector<SceneKey> skipped;
      {
        const std::lock_guard<std::mutex> lock(mutex);
        skipped.swap(skipped_pending);
      }
      if (!reliable) return;
      for (const auto& [generator_id, seq] : handed) session->Stored(generator_id, seq);
      for (const auto& [generator_id, seq] : skipped) session->Skipped(generator_id, seq);
      session->Credit();
      const DeliveryCounters delivery = session->delivery();
      const std::lock_guard<std::mutex> lock(mutex);
      for (const SceneKey& key : handed) taken_keys.erase(key);
      for (const SceneKey& key : skipped) taken_keys.erase(key);
      counters.lost = delivery.lost;
      counters.reasked = delivery.reasked;
    };
    while (!stop) {
      bus.HandleFor(20);
      credit_handed();
      {
        const std::lock_guard<std::mutex> lock(mutex);
        counters.fault_dropped = bus.state().fault_dropped();
        const AuthCounters refused = bus.state().auth_counters();
        counters.refused_unsigned = refused.unsigned_messages;
        counters.refused_forged = refused.forged;
        counters.refused_replayed = refused.replayed;
        counters.refused_relayed = refused.relayed;
      }
      // the client's credits, the status, and generators that use another key, which would
      // never be heard (an open best-effort stream reads signed scenes all the same; a reliable
      // one's credits would be refused): said, and named when the wait times out
      const int64_t handed = Counters().handed;
      try {
        session->Service(handed, handed);
      } catch (const std::runtime_error& mismatch) {
        throw FeedError(mismatch.what());
      }
      // every generator said its run is over: what came is all there is
      const std::string end = EndOfGenerators();
      if (!end.empty()) {
        std::fprintf(stderr, "stackgen-feed: %s\n", end.c_str());
        break;
      }
    }
    // generators stop waiting for this stream; it ended (its generators ended, or its learner
    // closed it)
    credit_handed();
    const int64_t handed = Counters().handed;
    session->Leave(handed, handed, kRunEnded);
  }

  // what reading a log has found so far
  struct LogReading {
    std::map<std::string, int64_t> other_channels;
    std::map<std::tuple<int32_t, int64_t, int64_t>, int64_t> seen;  // copies per scene
    int64_t scene_events = 0;
    KeyEvidence key_evidence;
    std::string first_refusal;
    bool refusal_reported = false;
  };

  // the key check of a scene event, as on a live bus (no liveness: a log is a recording): the
  // size of its body, or -1 when it is refused (counted; the first says why, once a scene of
  // the log passed: all refused fails the stream at the end, in one line)
  int64_t OpenLogEvent(const LogEvent& event, LogReading* reading) {
    std::string refused;
    const int64_t body = log_auth->Open(event.channel, event.data, event.size, &refused);
    reading->key_evidence.Note(*log_auth, event.data, event.size, body >= 0);
    if (body < 0) {
      const AuthCounters counted = log_auth->counters();
      const std::lock_guard<std::mutex> lock(mutex);
      counters.refused_unsigned = counted.unsigned_messages;
      counters.refused_forged = counted.forged;
      counters.refused_replayed = counted.replayed;
      counters.refused_relayed = counted.relayed;
      if (reading->first_refusal.empty()) reading->first_refusal = refused;
      return -1;
    }
    if (!reading->first_refusal.empty() && !reading->refusal_reported) {
      Report(reading->first_refusal);
      reading->refusal_reported = true;
    }
    return body;
  }

  // one scene event of a log: skipped when another shard's (before it is decoded), a repeat
  // (unless options.repeats) or bad; else queued once there is room in the queue and fewer than
  // `count` scenes are handed out or queued (one that then fails to decode makes room)
  void ReadLogScene(const LogEvent& event, size_t size, LogReading* reading) {
    // the header's seq and generator_id follow the fingerprint (big-endian int64 and int32)
    if (size >= 20 && ReadBigEndian(event.data, 8) == static_cast<uint64_t>(scene::getHash())) {
      const int64_t peeked_seq = static_cast<int64_t>(ReadBigEndian(event.data + 8, 8));
      const int32_t peeked_id = static_cast<int32_t>(ReadBigEndian(event.data + 16, 4));
      if (peeked_seq < 0 || !Wanted(peeked_id, peeked_seq)) return;
    }
    scene message;
    std::string why;
    if (!DecodeBounded(event.data, size, DecodeLimits{}, &message, &why)) {
      throw FeedError(log_path + ": the event at byte " + std::to_string(event.offset) + " on " +
                      options.channel + " is not a stackgen.scene of this build: " + why);
    }
    const int32_t generator_id = message.header.generator_id;
    const int64_t seq = message.header.seq;
    if (seq < 0 || !Wanted(generator_id, seq)) return;
    const int64_t occurrence = reading->seen[{generator_id, seq, message.header.seed}]++;
    {
      const std::lock_guard<std::mutex> lock(mutex);
      ++counters.received;
      if (occurrence > 0 && !options.repeats) {
        ++counters.duplicates;
        return;
      }
    }
    if (!Check(message)) return;
    {
      std::unique_lock<std::mutex> lock(mutex);
      changed.wait(lock, [&] {
        const int64_t held = counters.handed + static_cast<int64_t>(queue.size());
        return stop || (static_cast<int>(queue.size()) < options.queue &&
                        (options.count == 0 || held < options.count));
      });
      if (stop) throw StopReading{};
    }
    std::shared_ptr<FeedScene> prepared = Prepare(std::move(message));
    prepared->occurrence = occurrence;
    {
      const std::lock_guard<std::mutex> lock(mutex);
      queue.push_back(std::move(prepared));
    }
    changed.notify_all();
  }

  // the thread on a log: every scene event in file order, waiting while the queue is full
  void RunLog() {
    LogReading reading;
    LogSummary summary;
    try {
      summary = ReadLog(log_path, [&](const LogEvent& event) {
        if (stop) throw StopReading{};
        if (event.channel != options.channel) {
          ++reading.other_channels[event.channel];
          return;
        }
        ++reading.scene_events;
        const int64_t body = OpenLogEvent(event, &reading);
        if (body >= 0) ReadLogScene(event, static_cast<size_t>(body), &reading);
      });
    } catch (const StopReading&) {
      return;
    }
    if (reading.scene_events == 0) {
      std::string found;
      for (const auto& [channel, events] : reading.other_channels) {
        found += (found.empty() ? "" : ", ") + channel + " x" + std::to_string(events);
      }
      throw FeedError(log_path + " holds no events on channel " + options.channel +
                      (found.empty() ? "" : " (it has " + found + ")"));
    }
    // a log whose every scene was refused for its key: an error, not an empty stream
    const std::string mismatch = reading.key_evidence.Mismatch(
        *log_auth, "the scenes of " + log_path + " on " + options.channel);
    if (!mismatch.empty()) throw FeedError(mismatch);
    if (!reading.first_refusal.empty() && !reading.refusal_reported) Report(reading.first_refusal);
    if (summary.truncated_bytes > 0) {
      std::fprintf(stderr, "stackgen-feed: %s ends with a torn event of %lld bytes (skipped)\n",
                   log_path.c_str(), static_cast<long long>(summary.truncated_bytes));
    }
  }

  void Run() {
    try {
      if (log_path.empty()) {
        RunLive();
      } else {
        RunLog();
      }
    } catch (...) {
      const std::lock_guard<std::mutex> lock(mutex);
      error = std::current_exception();
    }
    {
      const std::lock_guard<std::mutex> lock(mutex);
      ended = true;
    }
    changed.notify_all();
  }
};

namespace {

// Throws FeedError naming the first option out of its range.
void CheckOptions(const SceneStreamOptions& options) {
  if (options.window < 1 || options.window > 10000) {
    throw FeedError("window must be 1..10000 scenes, got " + std::to_string(options.window));
  }
  if (options.queue < 1 || options.queue > kMaxQueue) {
    throw FeedError("queue must be 1.." + std::to_string(kMaxQueue) + " scenes, got " +
                    std::to_string(options.queue));
  }
  if (options.count < 0)
    throw FeedError("count must be >= 0, got " + std::to_string(options.count));
  if (options.shard_count < 1 || options.shard_count > kMaxShards) {
    throw FeedError("a stream splits between 1.." + std::to_string(kMaxShards) + " workers, not " +
                    std::to_string(options.shard_count));
  }
  if (options.decode_threads < 1 || options.decode_threads > 16) {
    throw FeedError("decode_threads must be 1..16, got " + std::to_string(options.decode_threads));
  }

  if (options.shard_index < 0 || options.shard_index >= options.shard_count) {
    throw FeedError("shard " + std::to_string(options.shard_index) + " is not one of 0.." +
                    std::to_string(options.shard_count - 1));
  }
  for (const int32_t generator_id : options.generator_ids) {
    if (generator_id < 0 || generator_id > kMaxGeneratorId) {
      throw FeedError("generator id " + std::to_string(generator_id) + " is outside 0.." +
                      std::to_string(kMaxGeneratorId));
    }
  }
  if (!(options.fault_drop >= 0 && options.fault_drop < 1)) {
    throw FeedError("fault_drop must be in [0, 1), got " + std::to_string(options.fault_drop));
  }
}

}  // namespace

SceneStream::SceneStream(const SceneStreamOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& impl = *impl_;
  impl.options = options;
  impl.pid = getpid();
  if (options.clock != nullptr) impl.clock = options.clock;
  impl.opened = impl.clock->Now();
  CheckOptions(options);
  impl.url = ResolveLcmUrl(options.url);
  impl.name = options.name.empty() ? DefaultName(options) : options.name;
  impl.log_path = LogPathOfUrl(impl.url);

  if (impl.url.rfind("file://", 0) == 0 && impl.log_path.empty()) {
    throw FeedError(impl.url + " names no log: use file:///path/to/scenes.lcmlog");
  }
  if (!impl.log_path.empty()) {
    // a log: refuse what is not one before the thread starts
    std::error_code error;
    if (!std::filesystem::exists(impl.log_path, error)) {
      throw FeedError("cannot open the log " + impl.log_path + " (" + impl.url + "): no such file");
    }
    if (std::filesystem::is_directory(impl.log_path, error)) {
      throw FeedError(impl.log_path + " is a folder, not an LCM log");
    }
    if (!IsLcmLog(impl.log_path)) {
      throw FeedError(impl.log_path + " is not an LCM log (it does not start with an LCM event)");
    }
    try {
      impl.log_auth = std::make_unique<MessageAuth>(
          options.open_bus ? "" : ResolveBusKeyFile(options.bus_key_file), false);
    } catch (const std::exception& error) {
      throw FeedError(error.what());
    }
  } else {
    ConsumerSessionOptions session_options;
    session_options.process = "stackgen-feed";
    session_options.name = impl.name;
    session_options.reliable = options.reliable;
    session_options.client.window = options.window;
    session_options.client.max_scenes = options.count;
    session_options.client.generator_ids = options.generator_ids;
    session_options.client.shard_index = options.shard_index;
    session_options.client.shard_count = options.shard_count;
    // a learner joins running generators where it hears them (see SceneClientOptions)
    session_options.client.join_where_heard = true;
    session_options.generator_channels = {options.channel, kConfigChannel};
    session_options.key_mismatch_s = kKeyMismatchS;
    session_options.status_period_s = options.publish_status ? 1 : 0;
    session_options.recent_scenes = kRecentKeys;
    session_options.clock = impl.clock;
    try {
      impl.session = std::make_unique<ConsumerSession>(
          std::make_unique<Bus>(impl.url,
                                ConsumerBusOptions(options.fault_drop, options.bus_key_file,
                                                   options.open_bus, options.replay, 0xFEED)),
          session_options);
    } catch (const std::exception& error) {
      throw FeedError(error.what());
    }
    impl.reliable = impl.session->reliable();
    Impl* raw = impl_.get();
    impl.session->SubscribeScenes(
        options.channel, [raw](const scene& message) { raw->OnLiveScene(message); },
        // a reliable window per generator, or the best-effort queue, plus room for resends
        std::max(64, 4 * std::max(options.window, options.queue)),
        [raw](const std::string& text) {
          raw->CountBad();
          raw->Report(text);
        });
    // the generators' configs too, for their key alone (Bus::WatchKeys): each generator
    // announces its config before its first scene and then every second
    impl.session->WatchGeneratorKeys();
    // and their status: the stream ends when their runs have
    impl.session->bus().Subscribe<status>(
        kStatusChannel, [raw](const status& message) { raw->OnStatus(message); }, 64,
        [](const std::string&) {});
  }
  for (int k = 0; k < options.decode_threads; ++k) {
    impl.decoders.emplace_back([raw = impl_.get()] { raw->RunDecoder(); });
  }
  impl.thread = std::thread([raw = impl_.get()] { raw->Run(); });
}

SceneStream::~SceneStream() {
  // a copy inherited by a forked process has no thread to stop: leave it alone
  if (impl_ && impl_->pid != getpid()) {
    impl_.release();
    return;
  }
  Close();
}

std::shared_ptr<FeedScene> SceneStream::Next(double timeout_s,
                                             const std::function<bool()>& interrupted) {
  Impl& impl = *impl_;
  if (impl.pid != getpid()) {
    throw FeedError(
        "this stream was opened in process " + std::to_string(impl.pid) + " and is read in " +
        std::to_string(getpid()) +
        ": a stream cannot be shared between processes (DataLoader workers); open one in each "
        "(stackgen.torch.StreamDataset does)");
  }
  const auto start = impl.clock->Now();
  std::unique_lock<std::mutex> lock(impl.mutex);
  while (true) {
    if (impl.closed) return nullptr;
    if (impl.options.count > 0 && impl.counters.handed >= impl.options.count) return nullptr;
    if (!impl.queue.empty()) {
      std::shared_ptr<FeedScene> next = std::move(impl.queue.front());
      impl.queue.pop_front();
      lock.unlock();
      impl.changed.notify_all();
      // its images, decoded in order of the queue by the decoder threads
      std::string why;
      const bool ready = next->WaitPrepared(&why);
      const SceneKey key{next->message().header.generator_id, next->message().header.seq};
      lock.lock();
      if (!ready && impl.closed) return nullptr;
      if (!ready) {
        ++impl.counters.bad_messages;
        if (impl.reliable) impl.skipped_pending.push_back(key);
        lock.unlock();
        impl.Report(why);
        lock.lock();
        continue;
      }
      if (impl.reliable) impl.handed_pending.push_back(key);
      ++impl.counters.handed;
      return next;
    }
    if (impl.error) std::rethrow_exception(impl.error);
    if (impl.ended || impl.closed) return nullptr;
    const auto now = impl.clock->Now();
    const double waited = std::chrono::duration<double>(now - start).count();
    if (timeout_s >= 0 && waited >= timeout_s) {
      const std::string keys = impl.session ? impl.session->KeyHint() : "";
      throw FeedTimeout("no scene on " + impl.options.channel + " of " + impl.url + " for " +
                        std::to_string(static_cast<int>(timeout_s + 0.5)) + " s: " +
                        (!keys.empty()          ? keys
                         : impl.session != nullptr ? impl.WaitingFor()
                                                   : std::string("is a generator publishing there?")));
    }
    // a learner that waits is told for what, at once and then now and again
    if (impl.session && waited >= kSayWaitingS &&
        (!impl.said_waiting ||
         std::chrono::duration<double>(now - impl.last_said).count() >= kSayAgainS)) {
      const std::string keys = impl.session->KeyHint();
      std::fprintf(stderr, "stackgen-feed: waiting for scenes on %s: %s\n",
                   impl.options.channel.c_str(), (keys.empty() ? impl.WaitingFor() : keys).c_str());
      impl.said_waiting = true;
      impl.last_said = now;
    }
    double slice = 0.1;
    if (timeout_s >= 0) slice = std::min(slice, timeout_s - waited);
    impl.changed.wait_for(lock, std::chrono::duration<double>(std::max(slice, 0.0)));
    if (interrupted && impl.queue.empty()) {
      lock.unlock();
      const bool stop = interrupted();
      lock.lock();
      if (stop) return nullptr;
    }
  }
}

void SceneStream::Close() {
  Impl& impl = *impl_;
  // a copy inherited by a forked process has no threads to stop (and its locks may be held)
  if (impl.pid != getpid()) return;
  {
    // under the mutex: the log reader checks `stop` in its wait
    const std::lock_guard<std::mutex> lock(impl.mutex);
    if (impl.closed) return;
    impl.closed = true;
    impl.stop = true;
  }
  impl.changed.notify_all();
  if (impl.thread.joinable()) impl.thread.join();
  {
    const std::lock_guard<std::mutex> lock(impl.mutex);
    impl.decoders_stop = true;
  }
  impl.decode_wanted.notify_all();
  for (std::thread& decoder : impl.decoders) decoder.join();
  // nothing waits for images that will not be decoded now
  for (const std::shared_ptr<FeedScene>& left : impl.to_decode) left->Fail("the stream closed");
  impl.to_decode.clear();
}

StreamCounters SceneStream::counters() const {
  // in a forked process the counters are the parent's, and its lock may be held
  if (impl_->pid != getpid()) return StreamCounters{};
  return impl_->Counters();
}
const std::string& SceneStream::url() const { return impl_->url; }
const std::string& SceneStream::name() const { return impl_->name; }
bool SceneStream::is_log() const { return !impl_->log_path.empty(); }

}  // namespace stackgen::feed
