#include "gen/scene/node.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <functional>
#include <future>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <stackgen/config_text.hpp>
#include <stackgen/model.hpp>
#include <stackgen/status.hpp>

#include "bus/auth.h"
#include "bus/channels.h"
#include "bus/udpm.h"
#include "contract/scene_contract.h"
#include "gen/config/config.h"
#include "session/delivery.h"

namespace stackgen {
namespace {

// consumers heard for this long that all use another bus key are said (seconds): they credit
// every 0.2 s, so one with the right key would have been heard by then
constexpr double kKeyMismatchS = 2.0;
// the models go out with every kModelPeriod-th status (about every 5 s)
constexpr int64_t kModelPeriod = 5;
// a running generator with no reliable consumer registered for this long says so (seconds)
constexpr double kAloneWarnS = 5.0;

std::string FormatMs(double total_ms, int64_t scenes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f", scenes > 0 ? total_ms / scenes : 0.0);
  return text;
}

// what the bus key cost, or that there was none: the end of the summary line
std::string AuthSummary(const Bus& bus, int64_t scenes) {
  if (!bus.state().keyed()) return "bus open (no key)";
  char text[96];
  std::snprintf(text, sizeof(text), "bus key: %.3f ms per scene signing and checking, ",
                scenes > 0 ? bus.state().auth_seconds() * 1e3 / static_cast<double>(scenes) : 0.0);
  return text + RefusedSummary(bus.state().auth_counters());
}

// Piles queued or settled ahead of the one being rendered, per physics thread. Piles differ
// widely in cost (a drop redrawn costs several); with one per thread a slow pile held the other
// threads idle once they had settled the next (the scenes go out in seq order). A settled pile is
// only its parts' types and poses. docs/results.md, "Speed", has the gain.
constexpr size_t kPilesAheadPerThread = 4;

double Seconds(Clock::TimePoint from, Clock::TimePoint to) {
  return std::chrono::duration<double>(to - from).count();
}

// Long-lived threads that start the tasks given to them in order (one thread: run in order).
// The pipeline's stages run on these rather than on a thread per scene: OpenCV keeps the
// thread-local buffers of threads that have exited, so a thread per scene grew the heap by about
// 0.7 KB per scene (heaptrack: 5.35 MB leaked after 300 scenes, 5.96 MB after 1,200).
class Worker {
 public:
  explicit Worker(int threads = 1) {
    for (int t = 0; t < threads; ++t) threads_.emplace_back([this] { Loop(); });
  }
  ~Worker() {
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (std::thread& thread : threads_) thread.join();
  }
  Worker(const Worker&) = delete;
  Worker& operator=(const Worker&) = delete;

  // Runs `task` after those given before; its result (or exception) comes through the future.
  template <typename Task>
  auto Submit(Task task) -> std::future<decltype(task())> {
    auto packaged = std::make_shared<std::packaged_task<decltype(task())()>>(std::move(task));
    std::future<decltype(task())> result = packaged->get_future();
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      tasks_.push_back([packaged] { (*packaged)(); });
    }
    wake_.notify_one();
    return result;
  }

 private:
  void Loop() {
    while (true) {
      std::function<void()> task;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, [this] { return stop_ || !tasks_.empty(); });
        if (tasks_.empty()) return;
        task = std::move(tasks_.front());
        tasks_.pop_front();
      }
      task();
    }
  }

  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> tasks_;
  bool stop_ = false;
  std::vector<std::thread> threads_;  // last: start once the rest is ready
};

}  // namespace

struct GeneratorNode::Impl {
  Impl(Bus* bus_in, SceneGenerator* generator_in, const LoadedConfig& config, uint64_t seed_in,
       int generator_id_in, const GeneratorNodeOptions& options_in);

  Bus& bus;
  SceneGenerator& generator;
  const uint64_t seed;
  const int generator_id;
  const GeneratorNodeOptions options;
  Clock& clock;
  const std::string name;  // stackgen/ID@HOST:PID, in status messages
  config_text config_message;
  std::unique_ptr<SceneServer> server;
  Subscription status_subscription;  // other generators' status (twins), ended with the node
  const std::vector<std::string> consumer_channels = {kCreditChannel, kResendChannel};

  // what was published, for status messages and the summary
  int64_t published = 0;
  int64_t scene_bytes = 0;  // of the scenes published (first time)
  int64_t next_seq = 0;
  StageTimes times;
  double publish_ms = 0;
  double held_back_s = 0;
  bool warned_of_twin = false;
  bool keys_said = false;  // consumers of another bus key, until one of this key is heard
  // no reliable consumer registered since this time (start, or when the last one left), and
  // whether that was said
  Clock::TimePoint alone_since;
  bool alone_said = false;
  int8_t run_state = kRunRunning;  // in every status: streams end once their generators' have
  int64_t published_at_last_status = 0;
  int64_t periods = 0;
  Clock::TimePoint start;
  Clock::TimePoint first_published;  // when the run's first scene went out
  Clock::TimePoint last_status;

  // the pipeline's state: the piles settling ahead (in seq order, up to kPilesAheadPerThread
  // per physics thread), the one being rendered, the scenes encoding (in seq order, at most one
  // per encoding thread)
  Worker physics_worker;
  Worker encode_worker;
  std::deque<std::future<SettledPile>> ahead;
  int64_t last_settling_first = -1;  // without picks: first seq of the pile queued last
  std::optional<SettledPile> current;
  std::deque<std::future<std::pair<scene, StageTimes>>> encoding;

  bool Stopped() const { return options.stop != nullptr && *options.stop; }
  status Status(int64_t next) const;
  status Counted(double since) const;
  void OnStatus(const status& other);
  void Announce();
  void Serve(int timeout_ms);
  std::string KeyHint() const;
  void Listen(double seconds, const std::function<bool()>& done);
  int64_t FirstSeq();
  void PublishPeriodic(bool force);
  void WarnIfAlone(Clock::TimePoint now);
  void PublishEnd(int8_t state);
  void WaitForConsumers(int timeout_ms);
  void SettleAhead(int64_t first_seq);
  void PublishEncoded();
  void Progress() const;
  void PrintSummary() const;
  void CheckDelivered() const;
};

GeneratorNode::Impl::Impl(Bus* bus_in, SceneGenerator* generator_in, const LoadedConfig& config,
                          uint64_t seed_in, int generator_id_in,
                          const GeneratorNodeOptions& options_in)
    : bus(*bus_in),
      generator(*generator_in),
      seed(seed_in),
      generator_id(generator_id_in),
      options(options_in),
      clock(options_in.clock != nullptr ? *options_in.clock : SteadyClock()),
      name([generator_id_in] {
        char host[256] = "localhost";
        gethostname(host, sizeof(host) - 1);
        return "stackgen/" + std::to_string(generator_id_in) + "@" + host + ":" +
               std::to_string(getpid());
      }()),
      alone_since(clock.Now()),
      physics_worker(std::max(1, options_in.physics_threads)),
      encode_worker(std::max(1, options_in.encode_threads)) {
  config_message.path = config.path;
  config_message.pbtxt = EffectiveConfigText(config.config);
  config_message.header.seq = -1;
  config_message.header.generator_id = generator_id;
  config_message.header.seed = static_cast<int64_t>(seed);

  // delivery: credits and resends of reliable consumers; a scene asked for after it left the
  // ring is made again (determinism makes it the same scene)
  SceneServerOptions server_options;
  server_options.generator_id = generator_id;
  server_options.ring_size = options.ring_size;
  server_options.consumer_timeout_s = options.consumer_timeout_s;
  server_options.stall_timeout_s = options.stall_timeout_s;
  server_options.clock = &clock;
  // a dataset of another run (seed or config) is not continued by this one
  server_options.run = RunName(static_cast<int64_t>(seed), config.path, config_message.pbtxt);
  server = std::make_unique<SceneServer>(
      &bus, server_options,
      [this](int64_t seq) {
        StageTimes not_reported;  // a scene made again is not a new one: its times stay out
        scene message = generator.Generate(seq, &not_reported);
        message.header.utime = UnixMicros();
        return EncodeMessage(message);
      },
      [this](const std::string& line) {
        if (options.progress) std::fprintf(stderr, "\n");
        std::fprintf(stderr, "stackgen: %s\n", line.c_str());
      });

  // another generator with this id on the bus would mix its scenes with ours
  status_subscription = bus.Subscribe<status>(
                               kStatusChannel, [this](const status& other) { OnStatus(other); },
                               100, [](const std::string&) {})
                            .EndWhenDropped();
}

// a status of this generator: who it is and its next seq, the counters left at 0
status GeneratorNode::Impl::Status(int64_t next) const {
  status message{};
  message.header.seq = -1;
  message.header.generator_id = generator_id;
  message.header.seed = static_cast<int64_t>(seed);
  message.header.utime = UnixMicros();
  message.next_seq = next;
  message.scenes_held = -1;
  message.process = "stackgen";
  message.name = name;
  return message;
}

// another generator with this id: the one that has published fewer scenes (on a tie, the larger
// name) gives way with an error, the other warns
void GeneratorNode::Impl::OnStatus(const status& other) {
  if (other.process != "stackgen" || other.header.generator_id != generator_id ||
      other.name == name) {
    return;
  }
  if (other.scenes > published || (other.scenes == published && other.name < name)) {
    throw std::runtime_error("another generator with --generator-id " +
                             std::to_string(generator_id) + " publishes on " + bus.url() + " (" +
                             other.name + ", " + std::to_string(other.scenes) +
                             " scenes): give each generator its own --generator-id");
  }
  if (!warned_of_twin) {
    std::fprintf(stderr,
                 "stackgen: warning: another generator with --generator-id %d (%s) "
                 "publishes on this bus; it has published less and gives way\n",
                 generator_id, other.name.c_str());
    warned_of_twin = true;
  }
}

// says so at once: a generator already running with this id then hears of this one (and warns)
// also when this one gives way before its first periodic status; then the config, before
// listening: a consumer hears this generator's key before any stranger's unsigned flood can make
// it conclude that the bus uses another key (the first scene may take seconds: piles, shader
// compilation)
void GeneratorNode::Impl::Announce() {
  bus.Publish(kStatusChannel, Status(-1));  // the next seq is not known before a resume
  config_message.header.utime = UnixMicros();
  bus.Publish(kConfigChannel, config_message);
}

// serves the consumers; one that holds scenes of another run stops this one with an error.
// Consumers heard for seconds that use another bus key (they would never be served) are said
// once, never a reason to stop: nothing of theirs is verified, and a stranger can send it. An
// open generator, which verifies nothing, stops then (its keyed consumers refuse its scenes)
void GeneratorNode::Impl::Serve(int timeout_ms) {
  server->Service(timeout_ms);
  if (!server->run_conflict().empty()) {
    throw std::runtime_error(server->run_conflict() +
                             ": continue it with that run's --seed and --config, or give the "
                             "writer another --out");
  }
  const std::string stalled = server->stalled();
  if (!stalled.empty()) throw std::runtime_error(stalled + "; stopping rather than waiting for ever");
  const std::string mismatch = bus.state().KeyMismatch(consumer_channels, kKeyMismatchS);
  // an open bus trusts every sender anyway: its keyed consumers would refuse every scene
  if (!bus.state().keyed() && !mismatch.empty()) throw std::runtime_error(mismatch);
  if (!keys_said && !mismatch.empty()) {
    if (options.progress) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "stackgen: warning: %s; going on\n", mismatch.c_str());
    keys_said = true;
  } else if (keys_said && bus.state().KeyMismatch(consumer_channels, 0).empty()) {
    keys_said = false;  // a consumer of this key came
  }
}

// " (LINE)" when consumers of another bus key were heard and none of this one, else "": the
// reason a wait for consumers may have ended
std::string GeneratorNode::Impl::KeyHint() const {
  const std::string mismatch = bus.state().KeyMismatch(consumer_channels, 0);
  return mismatch.empty() ? "" : " (" + mismatch + ")";
}

// hears which reliable consumers are there (they credit every 0.2 s)
void GeneratorNode::Impl::Listen(double seconds, const std::function<bool()>& done) {
  const Clock::TimePoint until =
      clock.Now() + std::chrono::duration_cast<Clock::TimePoint::duration>(
                        std::chrono::duration<double>(seconds));
  while (!Stopped() && clock.Now() < until && !done()) Serve(20);
}

// the seq to start at: 0, or with --resume what the reliable consumers stored through
int64_t GeneratorNode::Impl::FirstSeq() {
  Listen(0.5, [] { return false; });
  if (!options.resume) return options.first_seq;
  Listen(options.consumer_timeout_s, [this] { return server->ResumeSeq().has_value(); });
  if (!server->ResumeSeq()) {
    throw std::runtime_error("--resume: no reliable consumer (stackgen-coco) sent a credit on " +
                             bus.url() + " within " +
                             std::to_string(static_cast<int64_t>(options.consumer_timeout_s)) +
                             " s; start the writers first" + KeyHint());
  }
  Listen(0.5, [] { return false; });
  const int64_t first_seq = std::max(options.first_seq, *server->ResumeSeq());
  std::printf("stackgen: resuming at seq %lld (%d reliable consumers)\n",
              static_cast<long long>(first_seq), server->reliable_consumers());
  std::fflush(stdout);
  return first_seq;
}

// publishes the config and the status, about once a second, and the models at the start and
// every kModelPeriod periods after: writers that start later hear them within seconds, and a
// large mesh does not load the bus every second
void GeneratorNode::Impl::PublishPeriodic(bool force) {
  const Clock::TimePoint now = clock.Now();
  const double since = Seconds(last_status, now);
  if (!force && since < 1.0) return;
  config_message.header.utime = UnixMicros();
  bus.Publish(kConfigChannel, config_message);
  if (periods++ % kModelPeriod == 0) {
    for (model message : generator.Models()) {
      message.header = config_message.header;
      bus.Publish(kModelChannel, message);
    }
  }
  bus.Publish(kStatusChannel, Counted(since));
  last_status = now;
  published_at_last_status = published;
  WarnIfAlone(now);
}

// this generator's status with its counters now, `since` seconds after the status before
status GeneratorNode::Impl::Counted(double since) const {
  status message = Status(next_seq);
  message.scenes = published;
  message.scenes_rejected = times.redraws;
  message.redraws_unsettled = times.redraws_unsettled;
  message.redraws_outside = times.redraws_outside;
  message.redraws_penetrating = times.redraws_penetrating;
  message.scene_bytes = scene_bytes;
  message.rate_hz = since > 0 ? (published - published_at_last_status) / since : 0;
  const double n = published > 0 ? static_cast<double>(published) : 1.0;
  message.physics_ms = times.physics_ms / n;
  message.render_ms = times.render_ms / n;
  message.annotate_ms = times.annotate_ms / n;
  message.publish_ms = (times.encode_ms + publish_ms) / n;
  message.resent = server->resent();
  message.regenerated = server->regenerated();
  message.reliable_consumers = server->reliable_consumers();
  message.held_back_s = held_back_s;
  message.bad_messages = server->bad_messages();
  message.fault_dropped = bus.state().fault_dropped();
  const AuthCounters refused = bus.state().auth_counters();
  message.refused_unsigned = refused.unsigned_messages;
  message.refused_forged = refused.forged;
  message.refused_replayed = refused.replayed;
  message.refused_relayed = refused.relayed;
  message.run_state = run_state;
  return message;
}

// said while it runs, not only at the end: scenes published with no reliable consumer (a
// writer, a reliable stream) registered for kAloneWarnS go to listeners alone, or nowhere
void GeneratorNode::Impl::WarnIfAlone(Clock::TimePoint now) {
  if (run_state != kRunRunning) return;  // (the last status, on the way out)
  if (server->reliable_consumers() > 0) {
    alone_since = now;
    alone_said = false;
    return;
  }
  if (alone_said || options.no_consumer_ok || Seconds(alone_since, now) < kAloneWarnS) return;
  if (options.progress) std::fprintf(stderr, "\n");
  std::fprintf(stderr,
               "stackgen: warning: no reliable consumer (stackgen-coco, stackgen-bop, a reliable "
               "Stream) for %.0f s%s: %lld scenes published so far reach listeners only; start "
               "the writer on %s with this bus key, or pass --no-consumer-ok when listeners are "
               "meant%s\n",
               Seconds(alone_since, now), server->registrations() > 0 ? " (the last one left)" : "",
               static_cast<long long>(published), bus.url().c_str(), KeyHint().c_str());
  alone_said = true;
}

// the last status says how the run ended, three times over (a status is one datagram, and a
// stream ends on it); a run that reached its end sends its models once more before it: a BOP
// writer that lost them on the way waits for them after its last scene. Never throws: it also
// runs on the way out of an error
void GeneratorNode::Impl::PublishEnd(int8_t state) {
  run_state = state;
  try {
    if (state == kRunEnded) {
      for (model message : generator.Models()) {
        message.header = config_message.header;
        message.header.utime = UnixMicros();
        bus.Publish(kModelChannel, message);
      }
    }
    const status last = Counted(Seconds(last_status, clock.Now()));
    for (int k = 0; k < 3; ++k) {
      if (k > 0) std::this_thread::sleep_for(std::chrono::milliseconds(30));
      bus.Publish(kStatusChannel, last);
    }
  } catch (const std::exception&) {
    // the bus failed: the error on the way out says more
  }
}

// serves consumers for `timeout_ms`, counting the time as held back
void GeneratorNode::Impl::WaitForConsumers(int timeout_ms) {
  const Clock::TimePoint wait_start = clock.Now();
  Serve(timeout_ms);
  held_back_s += Seconds(wait_start, clock.Now());
  PublishPeriodic(false);
}

// the next piles settle on the physics threads while the scenes of this one are rendered, up to
// kPilesAheadPerThread piles per thread queued or settled ahead (each scene is the same either
// way: a pure function of its seq); with views_per_pile V, V scenes in a row show each state.
// With pick sequences each state follows from the one before: one pile (the state after the next
// pick) settles ahead.
void GeneratorNode::Impl::SettleAhead(int64_t first_seq) {
  const int views = generator.views_per_pile();
  const bool picks = generator.pick_sequence();
  const size_t most =
      picks ? 1 : static_cast<size_t>(std::max(1, options.physics_threads)) * kPilesAheadPerThread;
  SceneGenerator* scenes = &generator;
  while (ahead.size() < most) {
    // with picks the state after the one in hand; without, the pile after the one queued last
    // (pile k shows seqs k*V .. k*V+V-1, also when the run starts inside a pile)
    const int64_t next_first = picks ? (current ? current->first_seq + views : first_seq)
                               : last_settling_first >= 0 ? last_settling_first + views
                                                          : first_seq;
    if ((options.count != 0 && next_first >= options.first_seq + options.count) ||
        next_first > kMaxSeq) {
      return;
    }
    if (picks && current) {
      ahead.push_back(
          physics_worker.Submit([scenes, state = *current] { return scenes->SettleNext(state); }));
    } else {
      ahead.push_back(
          physics_worker.Submit([scenes, next_first] { return scenes->Settle(next_first); }));
    }
    last_settling_first = next_first - next_first % views;
  }
}

// the oldest scene encoding, published once the consumers' windows allow it
void GeneratorNode::Impl::PublishEncoded() {
  auto [message, encode_times] = encoding.front().get();
  encoding.pop_front();
  times.Add(encode_times);
  const int64_t seq = message.header.seq;
  // never more than a reliable consumer's window ahead of what it stored
  while (!server->MayPublish(seq) && !Stopped()) WaitForConsumers(20);
  if (Stopped()) return;

  // publish the scene and its labels.
  const Clock::TimePoint publish_start = clock.Now();
  message.header.utime = UnixMicros();
  std::vector<uint8_t> encoded = EncodeMessage(message);
  scene_bytes += static_cast<int64_t>(encoded.size());
  server->Publish(seq, std::move(encoded));
  bus.Publish(kLabelsChannel, LabelsOf(message));
  publish_ms += Seconds(publish_start, clock.Now()) * 1e3;
  if (published == 0) first_published = publish_start;
  ++published;
  next_seq = seq + 1;
  Serve(0);
  PublishPeriodic(false);
  Progress();
}

void GeneratorNode::Impl::Progress() const {
  if (!options.progress) return;
  const double rate = published / Seconds(start, clock.Now());
  if (options.count > 0) {
    std::fprintf(stderr, "\rstackgen: %lld/%lld scenes, %.2f scenes/s, %.0f s left   ",
                 static_cast<long long>(published), static_cast<long long>(options.count), rate,
                 (options.count - published) / rate);
  } else {
    std::fprintf(stderr, "\rstackgen: %lld scenes, %.2f scenes/s   ",
                 static_cast<long long>(published), rate);
  }
}

// the summary, also after SIGINT.
void GeneratorNode::Impl::PrintSummary() const {
  const double elapsed = Seconds(start, clock.Now());
  std::printf(
      "stackgen: %lld scenes in %.1f s (%.2f scenes/s)%s; per scene: physics %s ms, render %s "
      "ms, annotate %s ms, publish %s ms; %d drops redrawn (%d unsettled, %d outside the bin, %d "
      "interpenetrating); held back %.1f s by reliable consumers, %lld resent, %lld "
      "regenerated; %s\n",
      static_cast<long long>(published), elapsed, elapsed > 0 ? published / elapsed : 0.0,
      Stopped() ? ", stopped by signal" : "", FormatMs(times.physics_ms, published).c_str(),
      FormatMs(times.render_ms, published).c_str(), FormatMs(times.annotate_ms, published).c_str(),
      FormatMs(times.encode_ms + publish_ms, published).c_str(), times.redraws,
      times.redraws_unsettled, times.redraws_outside, times.redraws_penetrating, held_back_s,
      static_cast<long long>(server->resent()), static_cast<long long>(server->regenerated()),
      AuthSummary(bus, published).c_str());
  std::printf("stackgen: %s\n", ReceiveSummary(bus.state().receive_counters()).c_str());
}

// a run that ended by itself delivered to someone, unless told that listeners are enough
void GeneratorNode::Impl::CheckDelivered() const {
  if (Stopped() || options.no_consumer_ok) return;
  if (server->registrations() == 0) {
    throw std::runtime_error(
        "published " + std::to_string(published) + (published == 1 ? " scene" : " scenes") +
        " on " + bus.url() +
        " and no reliable consumer (stackgen-coco, stackgen-bop, a reliable Stream) took "
        "them: start the writer first, with this --lcm-url and bus key; pass --no-consumer-ok "
        "when listeners alone are meant" +
        KeyHint());
  }
  const std::vector<std::string> silent = server->gone_silent();
  if (!silent.empty()) {
    throw std::runtime_error(
        "reliable consumer " + silent.front() +
        (silent.size() > 1 ? " (and " + std::to_string(silent.size() - 1) + " more)" : "") +
        " went silent before it had stored every scene: its dataset lacks scenes; restart it "
        "with --resume and run this generator again (pass --no-consumer-ok to accept the loss)");
  }
}

GeneratorNode::GeneratorNode(Bus* bus, SceneGenerator* generator, const LoadedConfig& config,
                             uint64_t seed, int generator_id, const GeneratorNodeOptions& options)
    : impl_(std::make_unique<Impl>(bus, generator, config, seed, generator_id, options)) {}

GeneratorNode::~GeneratorNode() {
  // work in flight for scenes that will not be published (an error or a signal)
  for (auto& pending : impl_->encoding) pending.wait();
  for (auto& pile : impl_->ahead) pile.wait();
}

void GeneratorNode::Run() {
  try {
    RunScenes();
  } catch (...) {
    // (a run that ended, then found its scenes undelivered, said so already)
    if (impl_->run_state == kRunRunning) impl_->PublishEnd(kRunStopped);
    throw;
  }
}

void GeneratorNode::RunScenes() {
  Impl& node = *impl_;
  node.Announce();
  const int64_t first_seq = node.FirstSeq();
  node.next_seq = first_seq;
  node.start = node.clock.Now();
  node.alone_since = node.start;
  node.last_status = node.start - std::chrono::seconds(1);
  node.SettleAhead(first_seq);

  node.PublishPeriodic(true);
  // without --count, until a signal or the last seq of the id layout (contract/scene_contract.h)
  const int64_t last_seq =
      node.options.count > 0 ? node.options.first_seq + node.options.count - 1 : kMaxSeq;
  const int views = node.generator.views_per_pile();
  for (int64_t seq = first_seq; seq <= last_seq && !node.Stopped(); ++seq) {
    // nothing in flight: render only what may be published (later, rendering runs at most one
    // scene per encoding thread ahead of what was published)
    if (node.encoding.empty()) {
      while (!node.server->MayPublish(seq) && !node.Stopped()) node.WaitForConsumers(20);
      if (node.Stopped()) break;
    }
    RenderedScene rendered;
    try {
      if (!node.current || seq >= node.current->first_seq + views) {
        // while the pile settles (seconds; a drop redrawn: more) the generator stays heard:
        // its status and config every second, credits and resends served
        std::future<SettledPile>& settling = node.ahead.front();
        while (settling.wait_for(std::chrono::milliseconds(50)) != std::future_status::ready) {
          node.Serve(0);
          node.PublishPeriodic(false);
        }
        node.current = settling.get();
        node.ahead.pop_front();
        node.times.Add(node.current->times);
        node.SettleAhead(first_seq);
      }
      rendered = node.generator.Render(*node.current, seq, &node.times);
    } catch (...) {
      // the scenes in flight are made: publish them before the error ends the run
      while (!node.encoding.empty() && !node.Stopped()) node.PublishEncoded();
      throw;
    }
    // every encoding thread busy: the oldest scene goes out first
    const size_t encoders = static_cast<size_t>(std::max(1, node.options.encode_threads));
    while (node.encoding.size() >= encoders && !node.Stopped()) node.PublishEncoded();
    if (node.Stopped()) break;
    SceneGenerator* scenes = &node.generator;
    node.encoding.push_back(
        node.encode_worker.Submit([scenes, rendered = std::move(rendered)]() mutable {
          StageTimes encode_times;
          scene message = scenes->Encode(std::move(rendered), &encode_times);
          return std::make_pair(std::move(message), encode_times);
        }));
  }
  while (!node.encoding.empty() && !node.Stopped()) node.PublishEncoded();
  // work in flight for scenes that will not be published (stopped by a signal)
  for (auto& pending : node.encoding) pending.wait();
  for (auto& pile : node.ahead) pile.wait();
  // after the last scene, until every reliable consumer has stored it (or went silent)
  if (node.next_seq == last_seq + 1) {
    // a learner's stream joins a generator by hearing its scenes and credits within 0.2 s of
    // the first: a run may end before that, so one not heard of yet is given until a second
    // after the first scene (a run that lasted longer has heard from it already)
    if (node.server->reliable_consumers() == 0) {
      node.Listen(1.0 - Seconds(node.first_published, node.clock.Now()),
                  [&node] { return node.server->reliable_consumers() > 0; });
    }
    while (!node.server->AllStoredThrough(last_seq) && !node.Stopped()) node.WaitForConsumers(20);
    if (node.options.count == 0) {
      std::printf(
          "stackgen: generator %d reached the last seq, %lld: go on with another "
          "--generator-id\n",
          node.generator_id, static_cast<long long>(last_seq));
    }
  }
  node.PublishEnd(!node.Stopped() && node.next_seq == last_seq + 1 ? kRunEnded : kRunStopped);
  if (node.options.progress) std::fprintf(stderr, "\n");
  node.PrintSummary();
  node.CheckDelivered();
}

}  // namespace stackgen
