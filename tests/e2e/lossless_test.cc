// Delivery without loss, end to end: stackgen and stackgen-coco as separate processes over real
// UDP multicast, with injected loss, kill -9 and restarts, several generators and a write error.
// Every dataset is compared with one written by a plain run: the same images, byte for byte, and
// the same annotations.json apart from its info block.

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <stackgen/config_text.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/log.h"
#include "tests/support/datasets.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::ExpectSameDataset;
using testing::ImagesStored;
using testing::Process;
using testing::WaitForImages;

constexpr int kScenes = 14;
constexpr const char* kSeed = "5";

const std::string kBin = STACKGEN_BIN_DIR;

// the writer's command line
std::vector<std::string> Coco(const std::string& out, const std::string& url,
                              std::vector<std::string> extra = {}) {
  std::vector<std::string> argv = {kBin + "/stackgen-coco", "--out",     out, "--count",
                                   std::to_string(kScenes), "--lcm-url", url};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

// the generator's command line
std::vector<std::string> Generator(const std::string& url, const std::string& cache,
                                   std::vector<std::string> extra = {}) {
  std::vector<std::string> argv = {kBin + "/stackgen",
                                   "--config",
                                   testing::kLandedRule,
                                   "--count",
                                   std::to_string(kScenes),
                                   "--seed",
                                   kSeed,
                                   "--lcm-url",
                                   url,
                                   "--cache-dir",
                                   cache,
                                   "--consumer-timeout",
                                   "5"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

// listens on STACKGEN_STATUS in a thread of its own; keeps the last status of each process
class StatusListener {
 public:
  explicit StatusListener(const std::string& url) : bus_(url) {
    bus_.Subscribe<status>(kStatusChannel, [this](const status& message) {
      const std::lock_guard<std::mutex> lock(mutex_);
      last_[message.process] = message;
    });
    // an exception must not leave the thread (it would abort every test): keep its text
    thread_ = std::thread([this] {
      try {
        while (!stop_) bus_.HandleFor(50);
      } catch (const std::exception& error) {
        const std::lock_guard<std::mutex> lock(mutex_);
        error_ = error.what();
      }
    });
  }
  ~StatusListener() {
    stop_ = true;
    thread_.join();
  }
  // waits up to 10 s for a status of `process` whose next_seq (the generator) or scenes_held (a
  // consumer: scenes stored) is `seq`; false if none came
  bool WaitFor(const std::string& process, int64_t seq, status* out) {
    for (int i = 0; i < 500; ++i) {
      {
        const std::lock_guard<std::mutex> lock(mutex_);
        const auto found = last_.find(process);
        EXPECT_EQ(error_, "") << "the status listener stopped";
        if (!error_.empty()) return false;
        if (found != last_.end() &&
            (process == "stackgen" ? found->second.next_seq : found->second.scenes_held) == seq) {
          *out = found->second;
          return true;
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

 private:
  Bus bus_;
  std::mutex mutex_;
  std::map<std::string, status> last_;
  std::string error_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

class LosslessTest : public ::testing::Test {
 protected:
  // the reference, made once for the file's tests (CTest runs them in one process): a plain
  // run, no injected loss
  static void SetUpTestSuite() {
    shared_ = new testing::ScratchDir("stackgen-lossless-reference");
    cache_ = shared_->path() + "/cache";
    reference_ = shared_->path() + "/reference";
    const std::string url = testing::FreeMulticastUrl();
    Process coco(Coco(reference_, url), shared_->path() + "/reference-coco");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    Process generator(Generator(url, cache_), shared_->path() + "/reference-gen");
    ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
    ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  }
  static void TearDownTestSuite() {
    delete shared_;
    shared_ = nullptr;
  }

  static testing::ScratchDir* shared_;
  static std::string cache_;
  static std::string reference_;
  testing::ScratchDir scratch_{"stackgen-lossless"};
};

testing::ScratchDir* LosslessTest::shared_ = nullptr;
std::string LosslessTest::cache_;
std::string LosslessTest::reference_;

// with 10 % of the messages each process receives dropped (scenes at the writer; credits and
// resend requests at the generator), the dataset is complete and identical to the reference.
// The generator keeps only 1 scene for resending, so a scene lost before the next one was
// published is resent from the ring (the generator resends a tail the writer has not received
// while the next pile settles), one asked for later is made again from its seed: which of the
// two happens depends on timing, and both give the same bytes (a scene made again is the
// pipeline's: SceneGeneratorTest.PilesSettledOnAnotherThreadGiveTheSameScenes). Both
// processes' last status on STACKGEN_STATUS counts what happened.
TEST_F(LosslessTest, InjectedLossGivesTheSameDataset) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_.path() + "/lossy";
  StatusListener listener(url);
  Process coco(Coco(out, url, {"--fault-drop", "0.1"}), out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process generator(Generator(url, cache_, {"--fault-drop", "0.1", "--resend-ring", "1"}),
                    out + "-gen");
  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();

  // both published their counters on STACKGEN_STATUS; the last ones tell the story
  status writer{}, generator_status{};
  ASSERT_TRUE(listener.WaitFor("stackgen-coco", kScenes, &writer));
  EXPECT_EQ(writer.scenes, kScenes);
  EXPECT_GE(writer.received, kScenes);
  EXPECT_EQ(writer.lost, 0);
  EXPECT_GT(writer.fault_dropped, 0);
  EXPECT_EQ(writer.header.generator_id, -1);
  ASSERT_TRUE(listener.WaitFor("stackgen", kScenes, &generator_status));
  EXPECT_EQ(generator_status.scenes, kScenes);
  EXPECT_EQ(generator_status.next_seq, kScenes);
  EXPECT_EQ(generator_status.header.seq, -1);
  EXPECT_GT(generator_status.resent + generator_status.regenerated, 0);
  EXPECT_GT(generator_status.physics_ms, 0);
  const std::string summary = coco.Stdout();
  EXPECT_NE(summary.find(std::to_string(kScenes) + " images"), std::string::npos) << summary;
  EXPECT_NE(summary.find(", 0 missing"), std::string::npos) << summary;
  EXPECT_EQ(summary.find(", 0 messages dropped on purpose"), std::string::npos) << summary;
  ExpectSameDataset(reference_, out, kScenes);
}

// kill -9 of the writer mid-run, then the same writer again with --resume: every scene once.
TEST_F(LosslessTest, WriterKilledAndResumed) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_.path() + "/killed-writer";
  auto coco = std::make_unique<Process>(Coco(out, url), out + "-coco1");
  ASSERT_TRUE(coco->WaitForOutput("listening", 30)) << coco->Stderr();
  Process generator(Generator(url, cache_), out + "-gen");
  ASSERT_TRUE(WaitForImages(out, 5, 300));
  coco->Signal(SIGKILL);
  EXPECT_EQ(coco->Wait(10), 128 + SIGKILL);
  ASSERT_FALSE(fs::exists(out + "/annotations.json"));

  Process resumed(Coco(out, url, {"--resume"}), out + "-coco2");
  ASSERT_EQ(resumed.Wait(600), 0) << resumed.Stderr();
  EXPECT_NE(resumed.Stdout().find("resumed"), std::string::npos) << resumed.Stdout();
  ASSERT_EQ(generator.Wait(120), 0) << generator.Stderr();
  ExpectSameDataset(reference_, out, kScenes);
}

// kill -9 of the generator mid-run, then a restart with --resume: it continues where the writer
// stands, and the dataset is complete. A restart with another --seed or config is refused first.
TEST_F(LosslessTest, GeneratorKilledAndResumed) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_.path() + "/killed-generator";
  Process coco(Coco(out, url), out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  {
    Process generator(Generator(url, cache_), out + "-gen1");
    ASSERT_TRUE(WaitForImages(out, 5, 300));
    generator.Signal(SIGKILL);
    EXPECT_EQ(generator.Wait(10), 128 + SIGKILL);
  }
  const int stored = ImagesStored(out);
  ASSERT_LT(stored, kScenes);
  // another run cannot continue the dataset: another --seed, or another config, is refused with
  // one line naming both runs, and nothing is added (the writer refuses its scenes as well)
  const std::string tiny = std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.pbtxt";
  const std::vector<std::vector<std::string>> other_runs = {{"--resume", "--seed", "6"},
                                                            {"--resume", "--config", tiny}};
  for (const std::vector<std::string>& other : other_runs) {
    std::vector<std::string> argv = Generator(url, cache_, other);
    Process wrong(argv, out + "-wrong");
    EXPECT_EQ(wrong.Wait(120), 1) << wrong.Stdout();
    const std::string error = wrong.Stderr();
    EXPECT_NE(error.find("from another run (seed 5, "), std::string::npos) << error;
    EXPECT_NE(error.find(other[2] == "6" ? "than this one (seed 6" : "tiny.pbtxt"),
              std::string::npos)
        << error;
    EXPECT_EQ(ImagesStored(out), stored);
  }
  Process resumed(Generator(url, cache_, {"--resume"}), out + "-gen2");
  ASSERT_EQ(resumed.Wait(600), 0) << resumed.Stderr();
  // it continued at the writer's seq, not at 0
  const std::string said = resumed.Stdout();
  const size_t at = said.find("resuming at seq ");
  ASSERT_NE(at, std::string::npos) << said;
  EXPECT_GE(std::stoll(said.substr(at + 16)), stored - 2) << said;
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  ExpectSameDataset(reference_, out, kScenes);
}

// two generators with distinct ids publish into the same channels; the writer stores every scene
// of each once, kept apart by generator id, and generator 0's scenes equal the reference.
TEST_F(LosslessTest, TwoGenerators) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_.path() + "/two";
  std::vector<std::string> coco_argv = Coco(out, url);
  coco_argv[4] = std::to_string(2 * kScenes);  // --count
  Process coco(coco_argv, out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process first(Generator(url, cache_), out + "-gen0");
  Process second(Generator(url, cache_, {"--generator-id", "1"}), out + "-gen1");
  ASSERT_EQ(first.Wait(600), 0) << first.Stderr();
  ASSERT_EQ(second.Wait(600), 0) << second.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();

  const json dataset = testing::DatasetAnnotations(out);
  std::map<int, int> per_generator;
  for (const json& image : dataset["images"]) {
    ++per_generator[image["stackgen"]["generator_id"].get<int>()];
  }
  EXPECT_EQ(per_generator, (std::map<int, int>{{0, kScenes}, {1, kScenes}}));
  // generator 0's images are the reference's
  const json reference = testing::DatasetAnnotations(reference_);
  for (const json& image : reference["images"]) {
    const std::string name = image["file_name"];
    EXPECT_TRUE(testing::ReadFile(reference_ + "/images/" + name) ==
                testing::ReadFile(out + "/images/" + name))
        << name;
  }
}

// a full disk stops the writer with one line naming the file and the cause; what is on disk
// stays valid, and --resume once there is room completes the dataset. The disk is a small tmpfs
// (needs root to mount; skipped otherwise).
TEST_F(LosslessTest, FullDiskStopsCleanlyAndResumes) {
  const std::string out = scratch_.path() + "/full-disk";
  fs::create_directories(out);
  // room for about four of the reference's images
  std::vector<uintmax_t> sizes;
  for (const auto& entry : fs::directory_iterator(reference_ + "/images")) {
    sizes.push_back(entry.file_size());
  }
  std::sort(sizes.begin(), sizes.end());
  const uintmax_t room = 4 * sizes[sizes.size() / 2];
  const std::string mount =
      "mount -t tmpfs -o size=" + std::to_string(room) + " stackgen-test '" + out + "' 2>&1";
  if (std::system(mount.c_str()) != 0) {
    GTEST_SKIP() << "cannot mount a tmpfs (needs root): no full disk to test with";
  }
  struct Unmount {
    std::string dir;
    ~Unmount() { std::system(("umount '" + dir + "'").c_str()); }
  } unmount{out};

  const std::string url = testing::FreeMulticastUrl();
  Process coco(Coco(out, url), scratch_.path() + "/full-disk-coco1");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process generator(Generator(url, cache_), scratch_.path() + "/full-disk-gen");
  EXPECT_EQ(coco.Wait(600), 1);
  const std::string error = coco.Stderr();
  EXPECT_NE(error.find("stackgen-coco: error: "), std::string::npos) << error;
  EXPECT_NE(error.find(out), std::string::npos) << error;
  EXPECT_NE(error.find("No space left on device"), std::string::npos) << error;
  EXPECT_NE(error.find("--resume"), std::string::npos) << error;
  const int stored = ImagesStored(out);
  EXPECT_GT(stored, 0);
  EXPECT_LT(stored, kScenes);
  // no partial file is left behind
  for (const auto& entry : fs::directory_iterator(out + "/images")) {
    EXPECT_NE(entry.path().extension(), ".tmp") << entry.path();
  }

  // room again, and the same writer resumes
  ASSERT_EQ(std::system(("mount -o remount,size=256m '" + out + "'").c_str()), 0);
  Process resumed(Coco(out, url, {"--resume"}), scratch_.path() + "/full-disk-coco2");
  ASSERT_EQ(resumed.Wait(600), 0) << resumed.Stderr();
  ASSERT_EQ(generator.Wait(120), 0) << generator.Stderr();
  ExpectSameDataset(reference_, out, kScenes);
}

// two network namespaces joined by a veth pair (MTU 1500) stand for two hosts of a LAN: the
// generator in one, the writer in the other, multicast with ttl=1 over the link, and each side
// drops 30 % of the Ethernet frames it receives (nftables, at the device's ingress: IP fragments
// one by one); the dataset is complete and the reference's. With datagrams of 64 KB (mtu=65535 in
// the URL) not one scene arrives: 45 frames each. Needs root for `ip netns` and nftables
// (skipped otherwise).
TEST_F(LosslessTest, AcrossALossyLink) {
  const std::string ip = fs::exists("/usr/sbin/ip") ? "/usr/sbin/ip" : "/sbin/ip";
  const std::string tag = "sg" + std::to_string(getpid() % 100000);
  const std::string host_a = tag + "a", host_b = tag + "b";
  const std::string setup =
      ip + " netns add " + host_a + " && " + ip + " netns add " + host_b + " && " + ip +
      " link add " + host_a + " type veth peer name " + host_b + " && " + ip + " link set " +
      host_a + " netns " + host_a + " && " + ip + " link set " + host_b + " netns " + host_b +
      " && " + ip + " -n " + host_a + " addr add 10.213.0.1/24 dev " + host_a + " && " + ip +
      " -n " + host_b + " addr add 10.213.0.2/24 dev " + host_b + " && " + ip + " -n " + host_a +
      " link set " + host_a + " up && " + ip + " -n " + host_b + " link set " + host_b + " up && " +
      ip + " -n " + host_a + " route add 224.0.0.0/4 dev " + host_a + " && " + ip + " -n " +
      host_b + " route add 224.0.0.0/4 dev " + host_b + " 2>&1";
  struct Teardown {
    std::string command;
    ~Teardown() { std::system(command.c_str()); }
  } teardown{ip + " netns del " + host_a + " 2>/dev/null; " + ip + " netns del " + host_b +
             " 2>/dev/null"};
  if (std::system(setup.c_str()) != 0) {
    GTEST_SKIP() << "cannot make network namespaces and a veth pair (needs root and iproute2)";
  }
  const std::string nft = fs::exists("/usr/sbin/nft") ? "/usr/sbin/nft" : "/sbin/nft";
  for (const std::string& host : {host_a, host_b}) {
    const std::string in_host = ip + " netns exec " + host + " " + nft;
    const std::string loss =
        in_host + " add table netdev loss && " + in_host + " add chain netdev loss in '{ type " +
        "filter hook ingress device " + host + " priority 0; }' && " + in_host +
        " add rule netdev loss in numgen random mod 100 '<' 30 drop 2>&1";
    if (std::system(loss.c_str()) != 0) {
      GTEST_SKIP() << "cannot drop frames with nftables in a network namespace (needs nft, "
                      "from tools/install-deps, and the kernel's nf_tables)";
    }
  }

  // ttl=1: the datagrams may cross one link
  const std::string url = "udpm://239.255.76.67:" + std::to_string(testing::FreeUdpPort()) +
                          "?ttl=1&recv_buf_size=4194304";
  const std::string out = scratch_.path() + "/link";
  std::vector<std::string> coco_argv = {ip, "netns", "exec", host_b};
  for (const std::string& arg : Coco(out, url)) coco_argv.push_back(arg);
  Process coco(coco_argv, out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  std::vector<std::string> generator_argv = {ip, "netns", "exec", host_a};
  // the link's loss is tested here, not the consumer timeout (tested on its own): on a machine
  // busy with other tests a writer may send no credit for seconds, so the generator waits 30 s
  for (const std::string& arg : Generator(url, cache_, {"--consumer-timeout", "30"})) {
    generator_argv.push_back(arg);
  }
  Process generator(generator_argv, out + "-gen");
  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  EXPECT_NE(generator.Stderr().find("reliable consumer stackgen-coco@"), std::string::npos)
      << generator.Stderr();
  ExpectSameDataset(reference_, out, kScenes);
}

// the live stream recorded with tools/record (stackgen-record) and read back from the log
// (file://LOG?speed=0) by a second writer gives the same dataset as the live writer's; the
// recording holds the models the generator sends again at its end, which a BOP writer that lost
// the earlier ones waits for.
TEST_F(LosslessTest, RecordedStreamReplaysToTheSameDataset) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string log = scratch_.path() + "/live.lcmlog";
  Process record(
      {std::string(STACKGEN_SOURCE_DIR) + "/tools/record", "--lcm-url", url, "--out", log},
      scratch_.path() + "/record");
  ASSERT_TRUE(record.WaitForOutput("Ctrl-C stops", 30)) << record.Stderr();
  // the recorder listens once it has logged something (into LOG.part until it stops)
  Bus probe(url);
  config_text config{};
  config.path = "probe";
  const std::string part = log + ".part";
  for (int i = 0; i < 200 && (!fs::exists(part) || fs::file_size(part) == 0); ++i) {
    probe.Publish(kConfigChannel, config);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(fs::exists(part) && fs::file_size(part) > 0) << record.Stderr();

  const std::string live = scratch_.path() + "/live";
  Process coco(Coco(live, url), live + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process generator(Generator(url, cache_), live + "-gen");
  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  record.Signal(SIGINT);
  ASSERT_EQ(record.Wait(30), 0) << record.Stderr();

  const std::string replayed = scratch_.path() + "/replayed";
  Process replay(
      {kBin + "/stackgen-coco", "--lcm-url", "file://" + log + "?speed=0", "--out", replayed},
      replayed + "-coco");
  ASSERT_EQ(replay.Wait(120), 0) << replay.Stderr();
  ExpectSameDataset(reference_, live, kScenes);
  ExpectSameDataset(reference_, replayed, kScenes);

  // the generator sends its models once more just before its end: a live writer that lost every
  // model sent before the last scene still stores them, as it listens on for them once --count
  // scenes are stored. The recording without those models, played onto a bus of its own: 10 ms
  // between messages, then the end of the run 1.5 s after the last scene
  struct Event {
    std::string channel;
    std::vector<uint8_t> bytes;
  };
  std::vector<Event> events;
  ReadLog(log, [&](const LogEvent& event) {
    events.push_back({event.channel, {event.data, event.data + event.size}});
  });
  size_t last_scene = 0, end = 0;
  for (size_t i = 0; i < events.size(); ++i) {
    if (events[i].channel == kSceneChannel) last_scene = i;
    if (end == 0 && events[i].channel == kStatusChannel) {
      status message;
      ASSERT_GE(message.decode(events[i].bytes.data(), 0, static_cast<int>(events[i].bytes.size())),
                0);
      if (message.process == "stackgen" && message.run_state == kRunEnded) end = i;
    }
  }
  ASSERT_GT(end, last_scene) << "no end of the run after its last scene in " << log;
  EXPECT_EQ(events[end - 1].channel, kModelChannel) << "no model just before the run's end";
  const std::string late = scratch_.path() + "/late-models.lcmlog";
  {
    LogWriter writer(late);
    int64_t utime = 1'000'000;
    for (size_t i = 0; i < events.size(); ++i) {
      if (events[i].channel == kModelChannel && i < last_scene) continue;
      utime += i == last_scene + 1 ? 1'500'000 : 10'000;
      writer.WriteBytes(events[i].channel, events[i].bytes.data(), events[i].bytes.size(), utime);
    }
  }
  const std::string player = testing::FindOnPath("lcm-logplayer");
  ASSERT_FALSE(player.empty()) << "lcm-logplayer is not on PATH (Debian package liblcm-bin)";
  const std::string replay_url = testing::FreeMulticastUrl();
  const std::string bop = scratch_.path() + "/late-models-bop";
  Process bop_writer({kBin + "/stackgen-bop", "--lcm-url", replay_url, "--replay", "--out", bop,
                      "--count", std::to_string(kScenes)},
                     bop + "-log");
  ASSERT_TRUE(bop_writer.WaitForOutput("listening", 30)) << bop_writer.Stderr();
  Process play({player, "--lcm-url", replay_url, late}, bop + "-player");
  ASSERT_EQ(play.Wait(60), 0) << play.Stderr();
  ASSERT_EQ(bop_writer.Wait(60), 0) << bop_writer.Stderr();
  EXPECT_TRUE(fs::exists(bop + "/models/models_info.json")) << bop_writer.Stdout();
  EXPECT_TRUE(fs::exists(bop + "/models/obj_000001.ply")) << bop_writer.Stdout();
  EXPECT_EQ(bop_writer.Stderr().find("warning"), std::string::npos) << bop_writer.Stderr();
}

}  // namespace
}  // namespace stackgen
