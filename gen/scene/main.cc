// stackgen: drops copies of a part into a bin, renders the settled pile, labels every object and
// publishes each scene on LCM. Run with --help for the flags. This file parses them and builds
// the config, bus and scene generator; the generator node (node.h) does the rest.

#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <string>

#include "bus/auth.h"
#include "bus/bus.h"
#include "cli/flags.h"
#include "contract/scene_contract.h"
#include "gen/config/config.h"
#include "gen/scene/node.h"
#include "gen/scene/scene_generator.h"

namespace stackgen {
namespace {

std::atomic<bool> g_stop{false};

void OnSignal(int) { g_stop = true; }

// the cores this process may run on (its affinity: taskset, Slurm, a container's cpuset)
int UsableCores() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) != 0) return 1;
  return std::max(1, CPU_COUNT(&set));
}

// A scene's camera model and image encoding cost more than its render on a GPU: on a many-core
// host one thread for them would set the pace (docs/results.md, "Speed"). On a few cores the
// physics and the render keep them busy, and one thread is enough.
int DefaultEncodeThreads() { return std::max(1, UsableCores() / 4); }

constexpr const char* kUsage = R"(usage: stackgen [flags]

Drops copies of a part into a bin with Bullet physics, renders the settled pile headless
(EGL/OpenGL), labels every object and publishes each scene on LCM.

flags:
  --config FILE       generator config, protobuf text (default: %s)
  --count N           scenes to publish, then exit, 0..99999999; 0 = until SIGINT/SIGTERM
                      or the last seq, 99999998 (default: 0)
  --first-seq A       the first seq to publish (default: 0): with --count N, seqs A..A+N-1,
                      the same scenes a generator making seqs 0.. makes there (one task of a
                      cluster job: tools/task); writers take them with --first-seq A
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
  --stall-timeout S   a reliable consumer that still credits but has received none of the
                      scenes it lacks for S seconds, though they were sent again, ends the
                      run with an error naming it (the bus loses them; default: 60)
  --no-consumer-ok    a run that ends by itself (--count) exits 0 even when no reliable
                      consumer registered, or one went silent before storing every scene
                      (default: both end with an error, exit 1: a dataset missed them)
  --resend-ring N     recent scenes kept for resending, 1..10000 (default: 64; each takes the
                      size of an encoded scene, about 1 MB at 640x480); older ones are
                      regenerated from their seed when asked for
  --physics-threads N piles settled at once, one physics world per thread, 1..256 (default:
                      the cores this process may use, %d here), up to 4 piles per thread
                      settled ahead; the scenes are the same for any N (with
                      physics.pick_sequence one pile settles ahead)
  --encode-threads N  scenes given their camera model and image encoding at once, one per thread,
                      while the next renders, 1..64 (default: a quarter of the cores this process
                      may use, at least 1: %d here); published in seq order, the same for any N
  --fault-drop F      drop the fraction F in [0, 1) of the messages received (credits, resend
                      requests), from a fixed seed: for tests and demos (default: 0)
  --check             check the flags, the config (meshes and collision shapes included), the
                      bus and the renderer, print what would run, and exit 0 without
                      publishing (tools/run does this before it creates a dataset folder)
  --help              this text

channels published: STACKGEN_SCENE (labels + images), STACKGEN_LABELS (labels only),
STACKGEN_STATUS (1 Hz), STACKGEN_CONFIG (the config in force, 1 Hz), STACKGEN_MODEL (the
mesh, diameter and symmetries of each labelled class, every 5 s and at the end).
channels read: STACKGEN_CREDIT and STACKGEN_RESEND. Reliable consumers (stackgen-coco,
stackgen-bop) send
credits: the generator never runs more than a consumer's window ahead of what it has stored,
resends scenes a consumer missed (from the ring, else regenerated: scene k is always the same),
and after --count scenes waits until every reliable consumer has stored them all.
Best-effort listeners (stackgen-view, lcm-spy, lcm-logger) are never waited for; with only
them, pass --no-consumer-ok.
The next piles settle on the physics threads and scenes are encoded on the encoding threads
while the next one renders.
On exit and on SIGINT it prints the mean milliseconds per scene of each stage.
)";

int Run(int argc, char** argv) {
  // flags.
  std::string config_path = DefaultConfigPath(STACKGEN_DEFAULT_CONFIG);
  int64_t count = 0;
  int64_t first_seq = 0;
  int64_t seed_flag = 0;
  int generator_id = 0;
  std::string lcm_url;
  std::string cache_dir = DefaultCacheDir();
  bool resume = false;
  bool check = false;
  bool no_consumer_ok = false;
  int64_t consumer_timeout = 10;
  int64_t stall_timeout = 60;
  int ring_size = 64;
  int physics_threads = UsableCores();
  int encode_threads = DefaultEncodeThreads();
  BusOptions bus_options;
  FlagParser parser("stackgen");
  parser.String("--config", &config_path);
  parser.Int("--count", &count, 0, kMaxSeq + 1);
  parser.Int("--first-seq", &first_seq, 0, kMaxSeq);
  parser.Int("--seed", &seed_flag, 0, INT64_MAX);
  parser.Int("--generator-id", &generator_id, 0, kMaxGeneratorId);
  parser.LcmUrl(&lcm_url);
  parser.BusKey(&bus_options.key_file, &bus_options.open_bus);
  parser.String("--cache-dir", &cache_dir);
  parser.Switch("--resume", &resume);
  parser.Switch("--check", &check);
  parser.Switch("--no-consumer-ok", &no_consumer_ok);
  parser.Int("--consumer-timeout", &consumer_timeout, 1, 86400);
  parser.Int("--stall-timeout", &stall_timeout, 1, 86400);
  parser.Int("--resend-ring", &ring_size, 1, 10000);
  parser.Int("--physics-threads", &physics_threads, 1, 256);
  parser.Int("--encode-threads", &encode_threads, 1, 64);
  parser.FaultDrop(&bus_options.drop_receive_fraction);
  parser.ParseOrExit(argc, argv, [] {
    std::printf(kUsage, DefaultConfigPath(STACKGEN_DEFAULT_CONFIG).c_str(), UsableCores(),
                DefaultEncodeThreads());
  });
  if (first_seq + count - 1 > kMaxSeq) {
    std::fprintf(
        stderr,
        "stackgen: error: --first-seq %lld with --count %lld ends past the last seq, %lld\n",
        static_cast<long long>(first_seq), static_cast<long long>(count),
        static_cast<long long>(kMaxSeq));
    return 2;
  }
  const uint64_t seed = static_cast<uint64_t>(seed_flag);
  bus_options.fault_seed = 0x57AC0000u + static_cast<uint64_t>(generator_id);

  // config, bus and the scene generator: everything is checked before the first scene.
  const LoadedConfig config = LoadConfig(config_path);
  Bus bus(ResolveLcmUrl(lcm_url), bus_options);
  SceneGenerator generator(config, generator_id, seed, cache_dir);
  std::printf("stackgen: generator %d, seed %llu, config %s, bus %s (%s)\n%s\n", generator_id,
              static_cast<unsigned long long>(seed), config.path.c_str(), bus.url().c_str(),
              bus.state().keyed() ? ("signed with " + bus.state().key_file() + ", key id " +
                                     KeyIdText(bus.state().key_id()))
                                        .c_str()
                                  : "open: no bus key",
              generator.Description().c_str());
  std::printf(
      "pipeline: piles settled on %d physics thread%s (--physics-threads), scenes encoded on "
      "%d thread%s (--encode-threads), of the %d cores this process may use\n",
      physics_threads, physics_threads == 1 ? "" : "s", encode_threads,
      encode_threads == 1 ? "" : "s", UsableCores());
  std::fflush(stdout);
  if (check) {
    std::printf("stackgen: --check: the config, the bus and the renderer are usable\n");
    return 0;
  }

  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  GeneratorNodeOptions options;
  options.count = count;
  options.first_seq = first_seq;
  options.resume = resume;
  options.no_consumer_ok = no_consumer_ok;
  options.consumer_timeout_s = static_cast<double>(consumer_timeout);
  options.stall_timeout_s = static_cast<double>(stall_timeout);
  options.ring_size = ring_size;
  options.physics_threads = physics_threads;
  options.encode_threads = encode_threads;
  options.progress = isatty(STDERR_FILENO) != 0;
  options.stop = &g_stop;
  GeneratorNode node(&bus, &generator, config, seed, generator_id, options);
  node.Run();
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
