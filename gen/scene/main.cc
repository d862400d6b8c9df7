// stackgen: drops copies of a part into a bin, renders the settled pile, labels every object and
// publishes each scene on LCM. Run with --help for the flags.

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <functional>
#include <future>
#include <iostream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <stackgen/config_text.hpp>
#include <stackgen/model.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/delivery.h"
#include "bus/flags.h"
#include "bus/scene_contract.h"
#include "gen/config/config.h"
#include "gen/scene/scene_generator.h"

namespace stackgen {
namespace {

std::atomic<bool> g_stop{false};

// consumers heard for this long that all use another bus key stop the generator (seconds): they
// credit every 0.2 s, so one with the right key would have been heard by then
constexpr double kKeyMismatchS = 2.0;

void OnSignal(int) { g_stop = true; }

constexpr const char* kUsage = R"(usage: stackgen [flags]

Drops copies of a part into a bin with Bullet physics, renders the settled pile headless
(EGL/OpenGL), labels every object and publishes each scene on LCM.

flags:
  --config FILE       generator config, protobuf text (default: %s)
  --count N           scenes to publish, then exit, 0..99999999; 0 = until SIGINT/SIGTERM
                      or the last seq, 99999998 (default: 0)
  --seed S            base seed; scene k is a pure function of (config, S, G, k) (default: 0)
  --generator-id G    id of this generator, 0..65535, distinct per concurrent generator
                      (default: 0)
  --lcm-url URL       LCM bus (default: $STACKGEN_LCM_URL, else
                      udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304)
  --bus-key-file FILE sign every message with this shared key and refuse messages not signed
                      with it (default: $STACKGEN_BUS_KEY_FILE, else this user's key
                      ~/.config/stackgen/bus.key, made on first use; every process of the bus
                      needs the same key)
  --open-bus          no bus key: sign nothing and trust every sender on the group
  --cache-dir DIR     where convex decompositions are cached
                      (default: $XDG_CACHE_HOME/stackgen, else ~/.cache/stackgen)
  --resume            continue at the seq the reliable consumers (dataset writers) have
                      stored through: waits up to --consumer-timeout for their credits
  --consumer-timeout S  a reliable consumer silent for S seconds is no longer waited for
                      (default: 10)
  --no-consumer-ok    a run that ends by itself (--count) exits 0 even when no reliable
                      consumer registered, or one went silent before storing every scene
                      (default: both end with an error, exit 1: a dataset missed them)
  --resend-ring N     recent scenes kept for resending, 1..10000 (default: 64; each takes the
                      size of an encoded scene, about 1 MB at 640x480); older ones are
                      regenerated from their seed when asked for
  --fault-drop F      drop the fraction F in [0, 1) of the messages received (credits, resend
                      requests), from a fixed seed: for tests and demos (default: 0)
  --check             check the flags, the config (meshes and collision shapes included), the
                      bus and the renderer, print what would run, and exit 0 without
                      publishing (tools/run does this before it creates a dataset folder)
  --help              this text

channels published: STACKGEN_SCENE (labels + images), STACKGEN_LABELS (labels only),
STACKGEN_STATUS (1 Hz), STACKGEN_CONFIG (the config in force, 1 Hz), STACKGEN_MODEL (the
mesh, diameter and symmetries of each labelled class, every 5 s).
channels read: STACKGEN_CREDIT and STACKGEN_RESEND. Reliable consumers (stackgen-coco,
stackgen-bop) send
credits: the generator never runs more than a consumer's window ahead of what it has stored,
resends scenes a consumer missed (from the ring, else regenerated: scene k is always the same),
and after --count scenes waits until every reliable consumer has stored them all.
Best-effort listeners (stackgen-view, lcm-spy, lcm-logger) are never waited for; with only
them, pass --no-consumer-ok.
The next pile settles on a second thread and scenes are encoded on a third while the next one renders.
On exit and on SIGINT it prints the mean milliseconds per scene of each stage.
)";

std::string FormatMs(double total_ms, int64_t scenes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f", scenes > 0 ? total_ms / scenes : 0.0);
  return text;
}

// what the bus key cost, or that there was none: the end of the summary line
std::string AuthSummary(const Bus& bus, int64_t scenes) {
  if (!bus.keyed()) return "bus open (no key)";
  char text[96];
  std::snprintf(text, sizeof(text), "bus key: %.3f ms per scene signing and checking, ",
                scenes > 0 ? bus.auth_seconds() * 1e3 / static_cast<double>(scenes) : 0.0);
  return text + RefusedSummary(bus.auth_counters());
}

// One long-lived thread that runs the tasks given to it in order. The pipeline's stages run on
// two of these rather than on a thread per scene: OpenCV keeps the thread-local buffers of
// threads that have exited, so a thread per scene grew the heap by about 0.7 KB per scene
// (heaptrack: 5.35 MB leaked after 300 scenes, 5.96 MB after 1,200).
class Worker {
 public:
  Worker() : thread_([this] { Loop(); }) {}
  ~Worker() {
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    wake_.notify_one();
    thread_.join();
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
  std::thread thread_;  // last: starts once the rest is ready
};

int Run(int argc, char** argv) {
  // flags.
  std::string config_path = DefaultConfigPath(STACKGEN_DEFAULT_CONFIG);
  int64_t count = 0;
  int64_t seed_flag = 0;
  int generator_id = 0;
  std::string lcm_url;
  std::string cache_dir = DefaultCacheDir();
  bool resume = false;
  bool check = false;
  bool no_consumer_ok = false;
  int64_t consumer_timeout = 10;
  int ring_size = 64;
  BusOptions bus_options;
  FlagParser parser("stackgen");
  parser.String("--config", &config_path);
  parser.Int("--count", &count, 0, kMaxSeq + 1);
  parser.Int("--seed", &seed_flag, 0, INT64_MAX);
  parser.Int("--generator-id", &generator_id, 0, kMaxGeneratorId);
  parser.LcmUrl(&lcm_url);
  parser.BusKey(&bus_options.key_file, &bus_options.open_bus);
  parser.String("--cache-dir", &cache_dir);
  parser.Switch("--resume", &resume);
  parser.Switch("--check", &check);
  parser.Switch("--no-consumer-ok", &no_consumer_ok);
  parser.Int("--consumer-timeout", &consumer_timeout, 1, 86400);
  parser.Int("--resend-ring", &ring_size, 1, 10000);
  parser.FaultDrop(&bus_options.drop_receive_fraction);
  parser.ParseOrExit(
      argc, argv, [] { std::printf(kUsage, DefaultConfigPath(STACKGEN_DEFAULT_CONFIG).c_str()); });
  const uint64_t seed = static_cast<uint64_t>(seed_flag);
  const double consumer_timeout_s = static_cast<double>(consumer_timeout);
  bus_options.fault_seed = 0x57AC0000u + static_cast<uint64_t>(generator_id);

  // config, bus and the scene generator: everything is checked before the first scene.
  const LoadedConfig config = LoadConfig(config_path);
  Bus bus(ResolveLcmUrl(lcm_url), bus_options);
  SceneGenerator generator(config, generator_id, seed, cache_dir);
  std::printf(
      "stackgen: generator %d, seed %llu, config %s, bus %s (%s)\n%s\n", generator_id,
      static_cast<unsigned long long>(seed), config.path.c_str(), bus.url().c_str(),
      bus.keyed()
          ? ("signed with " + bus.key_file() + ", key id " + KeyIdText(bus.key_id())).c_str()
          : "open: no bus key",
      generator.Description().c_str());
  std::fflush(stdout);
  if (check) {
    std::printf("stackgen: --check: the config, the bus and the renderer are usable\n");
    return 0;
  }

  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  const bool progress = isatty(STDERR_FILENO) != 0;

  using Clock = std::chrono::steady_clock;

  // delivery: credits and resends of reliable consumers; a scene asked for after it left the
  // ring is made again (determinism makes it the same scene)
  SceneServerOptions server_options;
  server_options.generator_id = generator_id;
  server_options.ring_size = ring_size;
  server_options.consumer_timeout_s = consumer_timeout_s;
  // a dataset of another run (seed or config) is not continued by this one
  server_options.run =
      RunName(static_cast<int64_t>(seed), config.path, EffectiveConfigText(config.config));
  SceneServer server(
      &bus, server_options,
      [&](int64_t seq) {
        StageTimes not_reported;  // a scene made again is not a new one: its times stay out
        scene message = generator.Generate(seq, &not_reported);
        message.header.utime = UnixMicros();
        return EncodeMessage(message);
      },
      [&](const std::string& line) {
        if (progress) std::fprintf(stderr, "\n");
        std::fprintf(stderr, "stackgen: %s\n", line.c_str());
      });

  // another generator with this id on the bus would mix its scenes with ours: the one that has
  // published fewer scenes (on a tie, the larger name) gives way with an error, the other warns
  char host[256] = "localhost";
  gethostname(host, sizeof(host) - 1);
  const std::string name =
      "stackgen/" + std::to_string(generator_id) + "@" + host + ":" + std::to_string(getpid());
  int64_t published = 0;
  bool warned_of_twin = false;
  bus.Subscribe<status>(
      kStatusChannel,
      [&](const status& other) {
        if (other.process != "stackgen" || other.header.generator_id != generator_id ||
            other.name == name) {
          return;
        }
        if (other.scenes > published || (other.scenes == published && other.name < name)) {
          throw std::runtime_error("another generator with --generator-id " +
                                   std::to_string(generator_id) + " publishes on " + bus.url() +
                                   " (" + other.name + ", " + std::to_string(other.scenes) +
                                   " scenes): give each generator its own --generator-id");
        }
        if (!warned_of_twin) {
          std::fprintf(stderr,
                       "stackgen: warning: another generator with --generator-id %d (%s) "
                       "publishes on this bus; it has published less and gives way\n",
                       generator_id, other.name.c_str());
          warned_of_twin = true;
        }
      },
      100, [](const std::string&) {});
  // say so at once: a generator already running with this id then hears of this one (and
  // warns) also when this one gives way before its first periodic status
  {
    status hello{};
    hello.header.seq = -1;
    hello.next_seq = -1;  // not known before a resume is settled
    hello.scenes_held = -1;
    hello.header.generator_id = generator_id;
    hello.header.seed = static_cast<int64_t>(seed);
    hello.header.utime = UnixMicros();
    hello.process = "stackgen";
    hello.name = name;
    bus.Publish(kStatusChannel, hello);
  }

  // serves the consumers; one that holds scenes of another run stops this one with an error, and
  // so do consumers heard for seconds that use another bus key (they would never be served)
  const std::vector<std::string> consumer_channels = {kCreditChannel, kResendChannel};
  const auto serve = [&](int timeout_ms) {
    server.Service(timeout_ms);
    if (!server.run_conflict().empty()) {
      throw std::runtime_error(server.run_conflict() +
                               ": continue it with that run's --seed and --config, or give the "
                               "writer another --out");
    }
    const std::string mismatch = bus.KeyMismatch(consumer_channels, kKeyMismatchS);
    if (!mismatch.empty()) throw std::runtime_error(mismatch);
  };
  // hear which reliable consumers are there before the first scene (they credit every 0.2 s)
  const auto listen = [&](double seconds, const std::function<bool()>& done) {
    const Clock::time_point until = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                                       std::chrono::duration<double>(seconds));
    while (!g_stop && Clock::now() < until && !done()) serve(20);
  };
  config_text config_message;
  config_message.path = config.path;
  config_message.pbtxt = EffectiveConfigText(config.config);
  config_message.header.seq = -1;
  config_message.header.generator_id = generator_id;
  config_message.header.seed = static_cast<int64_t>(seed);
  // the config at once, before listening: a consumer hears this generator's key before any
  // stranger's unsigned flood can make it conclude that the bus uses another key (the first
  // scene may take seconds: piles, shader compilation)
  config_message.header.utime = UnixMicros();
  bus.Publish(kConfigChannel, config_message);
  listen(0.5, [] { return false; });
  int64_t first_seq = 0;
  if (resume) {
    listen(consumer_timeout_s, [&] { return server.ResumeSeq().has_value(); });
    if (!server.ResumeSeq()) {
      throw std::runtime_error("--resume: no reliable consumer (stackgen-coco) sent a credit on " +
                               bus.url() + " within " + std::to_string(consumer_timeout) +
                               " s; start the writers first");
    }
    listen(0.5, [] { return false; });
    first_seq = *server.ResumeSeq();
    std::printf("stackgen: resuming at seq %lld (%d reliable consumers)\n",
                static_cast<long long>(first_seq), server.reliable_consumers());
    std::fflush(stdout);
  }

  StageTimes times;
  double publish_ms = 0;
  double held_back_s = 0;
  int64_t published_at_last_status = 0;
  int64_t next_seq = first_seq;
  const Clock::time_point start = Clock::now();
  Clock::time_point last_status = start - std::chrono::seconds(1);

  // publishes the config and the status, about once a second, and the models every 5 s
  constexpr int64_t kModelPeriod = 5;
  int64_t periods = 0;
  const auto publish_periodic = [&](bool force) {
    const Clock::time_point now = Clock::now();
    const double since = std::chrono::duration<double>(now - last_status).count();
    if (!force && since < 1.0) return;
    config_message.header.utime = UnixMicros();
    bus.Publish(kConfigChannel, config_message);
    // the models at the start and every kModelPeriod periods after: writers that start later
    // hear them within seconds, and a large mesh does not load the bus every second
    if (periods++ % kModelPeriod == 0) {
      for (model message : generator.Models()) {
        message.header = config_message.header;
        bus.Publish(kModelChannel, message);
      }
    }
    status message{};
    message.header.seq = -1;
    message.next_seq = next_seq;
    message.scenes_held = -1;
    message.header.generator_id = generator_id;
    message.header.seed = static_cast<int64_t>(seed);
    message.header.utime = UnixMicros();
    message.process = "stackgen";
    message.name = name;
    message.scenes = published;
    message.scenes_rejected = times.redraws;
    message.rate_hz = since > 0 ? (published - published_at_last_status) / since : 0;
    const double n = published > 0 ? static_cast<double>(published) : 1.0;
    message.physics_ms = times.physics_ms / n;
    message.render_ms = times.render_ms / n;
    message.annotate_ms = times.annotate_ms / n;
    message.publish_ms = (times.encode_ms + publish_ms) / n;
    message.resent = server.resent();
    message.regenerated = server.regenerated();
    message.reliable_consumers = server.reliable_consumers();
    message.held_back_s = held_back_s;
    message.bad_messages = server.bad_messages();
    message.fault_dropped = bus.fault_dropped();
    const stackgen::AuthCounters refused = bus.auth_counters();
    message.refused_unsigned = refused.unsigned_messages;
    message.refused_forged = refused.forged;
    message.refused_replayed = refused.replayed;
    bus.Publish(kStatusChannel, message);
    last_status = now;
    published_at_last_status = published;
  };

  // serves consumers for `timeout_ms`, counting the time as held back
  const auto wait_for_consumers = [&](int timeout_ms) {
    const Clock::time_point wait_start = Clock::now();
    serve(timeout_ms);
    held_back_s += std::chrono::duration<double>(Clock::now() - wait_start).count();
    publish_periodic(false);
  };

  // the pipeline: the next pile (or, with pick sequences, the pile after the next pick) settles
  // on a second thread while the scenes of this one are rendered, labelled and published (each
  // scene is the same either way: a pure function of its seq); with views_per_pile V, V scenes
  // in a row show each state
  const int views = generator.views_per_pile();
  Worker physics_worker;
  Worker encode_worker;
  std::future<SettledPile> ahead;
  std::optional<SettledPile> current;
  const auto settle_ahead = [&] {
    const int64_t next_first = current ? current->first_seq + views : first_seq;
    if ((count != 0 && next_first >= count) || next_first > kMaxSeq) return;
    if (current) {
      ahead = physics_worker.Submit(
          [&generator, state = *current] { return generator.SettleNext(state); });
    } else {
      ahead =
          physics_worker.Submit([&generator, next_first] { return generator.Settle(next_first); });
    }
  };
  settle_ahead();

  // the last stage on a third thread: scene k is encoded while scene k + 1 renders; it is
  // published once encoded and allowed by the consumers' windows
  std::future<std::pair<scene, StageTimes>> encoding;
  const auto publish_encoded = [&] {
    auto [message, encode_times] = encoding.get();
    times.Add(encode_times);
    const int64_t seq = message.header.seq;
    // never more than a reliable consumer's window ahead of what it stored
    while (!server.MayPublish(seq) && !g_stop) wait_for_consumers(20);
    if (g_stop) return;

    // publish the scene and its labels.
    const Clock::time_point publish_start = Clock::now();
    message.header.utime = UnixMicros();
    server.Publish(seq, EncodeMessage(message));
    bus.Publish(kLabelsChannel, LabelsOf(message));
    publish_ms += std::chrono::duration<double, std::milli>(Clock::now() - publish_start).count();
    ++published;
    next_seq = seq + 1;
    serve(0);
    publish_periodic(false);

    if (progress) {
      const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
      const double rate = published / elapsed;
      if (count > 0) {
        std::fprintf(stderr, "\rstackgen: %lld/%lld scenes, %.2f scenes/s, %.0f s left   ",
                     static_cast<long long>(published), static_cast<long long>(count), rate,
                     (count - published) / rate);
      } else {
        std::fprintf(stderr, "\rstackgen: %lld scenes, %.2f scenes/s   ",
                     static_cast<long long>(published), rate);
      }
    }
  };

  publish_periodic(true);
  // without --count, until a signal or the last seq of the id layout (bus/scene_contract.h)
  const int64_t last_seq = count > 0 ? count - 1 : kMaxSeq;
  for (int64_t seq = first_seq; seq <= last_seq && !g_stop; ++seq) {
    // nothing in flight: render only what may be published (later, the one scene being
    // encoded is published first, and rendering runs at most one scene ahead of it)
    if (!encoding.valid()) {
      while (!server.MayPublish(seq) && !g_stop) wait_for_consumers(20);
      if (g_stop) break;
    }
    RenderedScene rendered;
    try {
      if (!current || seq >= current->first_seq + views) {
        current = ahead.get();
        times.Add(current->times);
        settle_ahead();
      }
      rendered = generator.Render(*current, seq, &times);
    } catch (...) {
      // the scene in flight is made: publish it before the error ends the run
      if (encoding.valid()) publish_encoded();
      throw;
    }
    if (encoding.valid()) publish_encoded();
    if (g_stop) break;
    encoding = encode_worker.Submit([&generator, rendered = std::move(rendered)]() mutable {
      StageTimes encode_times;
      scene message = generator.Encode(std::move(rendered), &encode_times);
      return std::make_pair(std::move(message), encode_times);
    });
  }
  if (encoding.valid() && !g_stop) publish_encoded();
  // work in flight for scenes that will not be published (stopped by a signal)
  if (encoding.valid()) encoding.wait();
  if (ahead.valid()) ahead.wait();
  // after the last scene, until every reliable consumer has stored it (or went silent)
  if (next_seq == last_seq + 1) {
    while (!server.AllStoredThrough(last_seq) && !g_stop) wait_for_consumers(20);
    if (count == 0) {
      std::printf(
          "stackgen: generator %d reached the last seq, %lld: go on with another "
          "--generator-id\n",
          generator_id, static_cast<long long>(last_seq));
    }
  }
  // consumers that use another key were heard, and none with this one: nothing was delivered
  const std::string mismatch = bus.KeyMismatch(consumer_channels, 0);
  if (!mismatch.empty()) throw std::runtime_error(mismatch);
  publish_periodic(true);
  if (progress) std::fprintf(stderr, "\n");

  // the summary, also after SIGINT.
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf(
      "stackgen: %lld scenes in %.1f s (%.2f scenes/s)%s; per scene: physics %s ms, render %s "
      "ms, annotate %s ms, publish %s ms; %d drops redrawn (%d unsettled, %d outside the bin, %d "
      "interpenetrating); held back %.1f s by reliable consumers, %lld resent, %lld "
      "regenerated; %s\n",
      static_cast<long long>(published), elapsed, elapsed > 0 ? published / elapsed : 0.0,
      g_stop ? ", stopped by signal" : "", FormatMs(times.physics_ms, published).c_str(),
      FormatMs(times.render_ms, published).c_str(), FormatMs(times.annotate_ms, published).c_str(),
      FormatMs(times.encode_ms + publish_ms, published).c_str(), times.redraws,
      times.redraws_unsettled, times.redraws_outside, times.redraws_penetrating, held_back_s,
      static_cast<long long>(server.resent()), static_cast<long long>(server.regenerated()),
      AuthSummary(bus, published).c_str());
  std::printf("stackgen: %s\n", ReceiveSummary(bus.receive_counters()).c_str());

  // a run that ended by itself delivered to someone, unless told that listeners are enough
  if (!g_stop && !no_consumer_ok) {
    if (server.registrations() == 0) {
      throw std::runtime_error(
          "published " + std::to_string(published) + (published == 1 ? " scene" : " scenes") +
          " on " + bus.url() +
          " and no reliable consumer (stackgen-coco, stackgen-bop, a reliable Stream) took "
          "them: start the writer first, with this --lcm-url and bus key; pass --no-consumer-ok "
          "when listeners alone are meant");
    }
    const std::vector<std::string> silent = server.gone_silent();
    if (!silent.empty()) {
      throw std::runtime_error(
          "reliable consumer " + silent.front() +
          (silent.size() > 1 ? " (and " + std::to_string(silent.size() - 1) + " more)" : "") +
          " went silent before it had stored every scene: its dataset lacks scenes; restart it "
          "with --resume and run this generator again (pass --no-consumer-ok to accept the loss)");
    }
  }
  return 0;
}

}  // namespace
}  // namespace stackgen

int main(int argc, char** argv) {
  try {
    return stackgen::Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen: error: %s\n", error.what());
    return 1;
  }
}
