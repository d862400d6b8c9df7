// Trust (docs/design.md, "Trust"): a generator and a writer that share a bus key, attacked by strangers on the
// same multicast group: stackgen-forger (tests/e2e/forger.cc) with no key and with another key
// forges scenes, impersonates the writer, offers a window of 0, floods resend requests and fuzzes
// every channel; lcm-logplayer replays a recording of the run into it. Every such message is
// refused and counted, the generator is not held back, and the dataset equals a clean run's.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "tests/support/datasets.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::ExpectSameDataset;
using testing::ImagesStored;
using testing::Process;

constexpr int kScenes = 12;
const std::string kBin = STACKGEN_BIN_DIR;
const std::string kForger = std::string(STACKGEN_TEST_BIN_DIR) + "/stackgen-forger";

std::vector<std::string> Coco(const std::string& out, const std::string& url) {
  return {kBin + "/stackgen-coco", "--out",     out, "--count",
          std::to_string(kScenes), "--lcm-url", url};
}

std::vector<std::string> Generator(const std::string& url, const std::string& cache) {
  return {kBin + "/stackgen",
          "--config",
          testing::kLandedRule,
          "--count",
          std::to_string(kScenes),
          "--seed",
          "5",
          "--lcm-url",
          url,
          "--cache-dir",
          cache,
          "--consumer-timeout",
          "5"};
}

// the resident memory of a process now, kB (0 once it is gone)
int64_t ResidentKb(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stoll(line.substr(6));
  }
  return 0;
}

// the three refusal counts a summary line ends with: "refused U unsigned, F forged or altered,
// R replayed"; -1s when the line is missing
std::vector<int64_t> Refused(const std::string& output) {
  const std::regex pattern(R"(refused (\d+) unsigned, (\d+) forged or altered, (\d+) replayed)");
  std::smatch match;
  if (!std::regex_search(output, match, pattern)) return {-1, -1, -1};
  return {std::stoll(match[1]), std::stoll(match[2]), std::stoll(match[3])};
}

class TrustTest : public ::testing::Test {
 protected:
  // the reference, made once for the file's tests (CTest runs them in one process)
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir("trust");
    ASSERT_NE(std::getenv("STACKGEN_BUS_KEY_FILE"), nullptr)
        << "the suite runs with a bus key (tests/CMakeLists.txt); run this through ctest";
    cache_ = scratch_->path() + "/cache";
    reference_ = scratch_->path() + "/reference";
    recording_ = scratch_->path() + "/reference.lcmlog";
    logger_ = testing::FindOnPath("lcm-logger");
    player_ = testing::FindOnPath("lcm-logplayer");
    ASSERT_FALSE(logger_.empty() || player_.empty())
        << "lcm-logger and lcm-logplayer are not on PATH (Debian package liblcm-bin)";
    // the reference: a plain run with the key and no stranger, recorded; its peak memory too
    const std::string url = testing::FreeMulticastUrl();
    Process record(
        {logger_, "--lcm-url", url, "--channel", "STACKGEN_(SCENE|CONFIG)", "--quiet", recording_},
        reference_ + "-logger");
    Process coco(Coco(reference_, url), reference_ + "-coco");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    Process generator(Generator(url, cache_), reference_ + "-gen");
    Watch(generator, coco, &reference_peak_gen_kb_, &reference_peak_coco_kb_);
    ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
    ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
    record.Signal(SIGINT);
    ASSERT_EQ(record.Wait(10), 0) << record.Stderr();
  }

  // samples both processes' memory every 50 ms until the generator exits (at most 600 s)
  static void Watch(Process& generator, Process& coco, int64_t* peak_gen_kb,
                    int64_t* peak_coco_kb) {
    for (int i = 0; i < 12000; ++i) {
      const int64_t gen_kb = ResidentKb(generator.pid());
      if (gen_kb == 0 || generator.Exited()) break;
      *peak_gen_kb = std::max(*peak_gen_kb, gen_kb);
      *peak_coco_kb = std::max(*peak_coco_kb, ResidentKb(coco.pid()));
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

  static void TearDownTestSuite() {
    delete scratch_;
    scratch_ = nullptr;
  }

  static testing::ScratchDir* scratch_;
  static std::string cache_;
  static std::string reference_;
  static std::string recording_;  // the reference run's STACKGEN_SCENE and STACKGEN_CONFIG
  static std::string logger_;
  static std::string player_;
  static int64_t reference_peak_gen_kb_;
  static int64_t reference_peak_coco_kb_;
};

testing::ScratchDir* TrustTest::scratch_ = nullptr;
std::string TrustTest::cache_;
std::string TrustTest::reference_;
std::string TrustTest::recording_;
std::string TrustTest::logger_;
std::string TrustTest::player_;
int64_t TrustTest::reference_peak_gen_kb_ = 0;
int64_t TrustTest::reference_peak_coco_kb_ = 0;

// Strangers without the key, or with another one, forge scenes, impersonate the writer (all
// stored, leaving), offer a window of 0 and flood resend requests for the whole run, and a
// recording of the run's first seconds is replayed into it: each kind is refused and counted by
// both processes, the generator finishes, and the dataset is the clean run's.
TEST_F(TrustTest, StrangersAreRefusedAndCounted) {
  const std::string& logger = logger_;
  const std::string& player = player_;
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_->path() + "/attacked";
  const std::string wrong_key = scratch_->path() + "/wrong.key";
  std::ofstream(wrong_key) << "not the key of this deployment, but long enough to be one\n";
  chmod(wrong_key.c_str(), 0600);

  const std::string recording = scratch_->path() + "/recording.lcmlog";
  Process record({logger, "--lcm-url", url, "--quiet", recording}, out + "-logger");
  Process coco(Coco(out, url), out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process stranger({kForger, "--lcm-url", url, "--seconds", "600"}, out + "-stranger");
  Process impostor({kForger, "--lcm-url", url, "--seconds", "600", "--bus-key-file", wrong_key},
                   out + "-impostor");
  Process generator(Generator(url, cache_), out + "-gen");
  // the first scenes recorded, then played back into the running pipeline
  for (int i = 0; i < 6000 && ImagesStored(out) < 3 && !generator.Exited(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  record.Signal(SIGINT);
  record.Wait(10);
  // 20 times as fast: the recorded scenes come back within a fraction of a second, while the
  // writer still runs (at 1x they came after the generator's start-up time again, and under load
  // the writer could have stored its last scene and left before: nothing replayed reached it)
  Process replay({player, "--speed", "20", "--lcm-url", url, recording}, out + "-replay");

  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  replay.Wait(60);
  ExpectSameDataset(reference_, out, kScenes);

  // the generator refused credits and resend requests of each kind; the writer, scenes
  const std::vector<int64_t> generator_refused = Refused(generator.Stdout());
  const std::vector<int64_t> writer_refused = Refused(coco.Stdout());
  std::printf(
      "refused (unsigned, forged or altered, replayed): generator %lld, %lld, %lld; "
      "writer %lld, %lld, %lld\n",
      static_cast<long long>(generator_refused[0]), static_cast<long long>(generator_refused[1]),
      static_cast<long long>(generator_refused[2]), static_cast<long long>(writer_refused[0]),
      static_cast<long long>(writer_refused[1]), static_cast<long long>(writer_refused[2]));
  for (size_t kind = 0; kind < 3; ++kind) {
    EXPECT_GT(generator_refused[kind], 0) << "kind " << kind << ": " << generator.Stdout();
    EXPECT_GT(writer_refused[kind], 0) << "kind " << kind << ": " << coco.Stdout();
  }
  // the one offering no window never registered; the stranger did hear the writer's name
  stranger.Signal(SIGINT);
  EXPECT_EQ(stranger.Wait(10), 0);
  EXPECT_EQ(generator.Stderr().find("stranger"), std::string::npos) << generator.Stderr();
  EXPECT_NE(stranger.Stdout().find("writer stackgen-coco@"), std::string::npos)
      << stranger.Stdout();
}

// Thousands of random and mutated messages on every channel, unsigned and signed (those signed
// on channels that cannot add a scene), with a short version of the floods (tiny fragments of
// messages never completed, fragment-0 claims of 256 MiB, recorded liveness challenges played
// back), leave both processes running with memory near a clean run's, and the dataset intact.
TEST_F(TrustTest, FuzzLeavesBothRunning) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_->path() + "/fuzzed";
  Process coco(Coco(out, url), out + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process fuzzer({kForger, "--lcm-url", url, "--seconds", "4", "--no-attacks", "--fuzz", "4000",
                  "--signed-fuzz", "--bus-key-file", std::getenv("STACKGEN_BUS_KEY_FILE"),
                  "--fragment-flood", "40000", "--claims", "4000", "--challenge-replay", "4000"},
                 out + "-fuzzer");
  Process generator(Generator(url, cache_), out + "-gen");
  int64_t peak_gen_kb = 0, peak_coco_kb = 0;
  Watch(generator, coco, &peak_gen_kb, &peak_coco_kb);
  ASSERT_EQ(fuzzer.Wait(60), 0) << fuzzer.Stderr();
  EXPECT_NE(fuzzer.Stdout().find("4000 fuzzed"), std::string::npos) << fuzzer.Stdout();
  EXPECT_NE(fuzzer.Stdout().find("40000 of the fragment flood, 4000 claims"), std::string::npos)
      << fuzzer.Stdout();
  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  ExpectSameDataset(reference_, out, kScenes);
  std::printf(
      "peak resident memory, clean run -> fuzzed: generator %lld -> %lld kB, writer %lld "
      "-> %lld kB\n",
      static_cast<long long>(reference_peak_gen_kb_), static_cast<long long>(peak_gen_kb),
      static_cast<long long>(reference_peak_coco_kb_), static_cast<long long>(peak_coco_kb));
  // bounded: within 64 MB of the clean run's peak (a scene is about 1 MB encoded)
  EXPECT_LT(peak_gen_kb, reference_peak_gen_kb_ + 65536)
      << "generator peak " << peak_gen_kb << " kB, clean run " << reference_peak_gen_kb_;
  EXPECT_LT(peak_coco_kb, reference_peak_coco_kb_ + 65536)
      << "writer peak " << peak_coco_kb << " kB, clean run " << reference_peak_coco_kb_;
  // and the fuzz reached them: refused by the key check, or signed and then refused as invalid
  const std::vector<int64_t> writer_refused = Refused(coco.Stdout());
  EXPECT_GT(writer_refused[0], 0) << coco.Stdout();
}

// A recording of the keyed reference run played onto another bus by lcm-logplayer, seconds
// after it was made, into a fresh writer is refused whole (signed for the bus it was recorded
// on: relayed, counted so, with a warning that names --replay; played onto its own bus its
// sender would not answer the liveness check, LivenessCheckTest.ARecordingNeverAnswers); told
// that it reads a replay, a writer stores it: the reference dataset, file for file.
TEST_F(TrustTest, ARecordingIsTakenOnlyAsAReplay) {
  const std::string refused = scratch_->path() + "/refused";
  {
    const std::string url = testing::FreeMulticastUrl();
    Process coco(Coco(refused, url), refused + "-coco");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    // at half speed: a run of a few seconds sends for longer than the 2 s after which a sender
    // that does not answer is taken for a recording
    Process player({player_, "--lcm-url", url, "-s", "0.5", recording_}, refused + "-player");
    ASSERT_EQ(player.Wait(120), 0) << player.Stderr();
    coco.Signal(SIGINT);
    ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
    EXPECT_EQ(ImagesStored(refused), 0);
    EXPECT_NE(coco.Stderr().find("for another bus (group and port)"), std::string::npos)
        << coco.Stderr();
    EXPECT_NE(coco.Stderr().find("--replay"), std::string::npos) << coco.Stderr();
    const std::regex relayed(R"(([1-9]\d*) relayed from another bus)");
    EXPECT_TRUE(std::regex_search(coco.Stdout(), relayed)) << coco.Stdout();
  }
  const std::string taken = scratch_->path() + "/taken";
  const std::string url = testing::FreeMulticastUrl();
  std::vector<std::string> argv = Coco(taken, url);
  argv.push_back("--replay");
  Process coco(argv, taken + "-coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process player({player_, "--lcm-url", url, "-s", "4", recording_}, taken + "-player");
  ASSERT_EQ(player.Wait(120), 0) << player.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();
  ExpectSameDataset(reference_, taken, kScenes);
}

// A writer and a generator with different bus keys, or an open generator (--open-bus) and a
// keyed writer: the writer says so within seconds in one warning line that names the mismatch
// (and the key ids) and goes on waiting, not saying "no generator heard" (nothing it cannot
// verify stops it), and stores nothing; the keyed generator makes its scenes and ends with exit
// 1, its error naming the mismatch as the reason no reliable consumer took them; the open one,
// which verifies nothing, stops within seconds with that line. A writer that stopped at the
// first mismatch would fail the writer's checks.
TEST(TrustKeysTest, DifferentKeysAreSaidAndStopNoKeyedProcess) {
  const testing::ScratchDir scratch("trust-keys");
  const std::string wrong_key = scratch.path() + "/wrong.key";
  std::ofstream(wrong_key) << "not the key of this deployment, but long enough to be one\n";
  chmod(wrong_key.c_str(), 0600);
  struct Case {
    std::string name;
    std::vector<std::string> writer_flags, generator_flags;
    std::string writer_says, generator_error, generator_says;
  };
  const std::vector<Case> cases = {
      {"another key",
       {"--bus-key-file", wrong_key},
       {},
       "signed with another bus key (key id",
       "stackgen: error: published 12 scenes",
       "signed with another bus key (key id"},
      {"an open generator",
       {},
       {"--open-bus"},
       "are not signed",
       "stackgen: error: the messages on STACKGEN_CREDIT",
       "runs with an open bus"}};
  const std::string warning = "stackgen-coco: warning: the messages on ";
  for (const Case& test : cases) {
    SCOPED_TRACE(test.name);
    const std::string url = testing::FreeMulticastUrl();
    const std::string out = scratch.path() + "/" + test.name;
    std::vector<std::string> coco_argv = Coco(out, url);
    coco_argv.insert(coco_argv.end(), test.writer_flags.begin(), test.writer_flags.end());
    Process coco(coco_argv, out + "-coco");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    std::vector<std::string> generator_argv = Generator(url, scratch.path() + "/cache");
    generator_argv.insert(generator_argv.end(), test.generator_flags.begin(),
                          test.generator_flags.end());
    Process generator(generator_argv, out + "-gen");
    EXPECT_TRUE(coco.WaitForError(warning, 30)) << coco.Stderr();
    EXPECT_EQ(generator.Wait(300), 1) << generator.Stderr();
    std::this_thread::sleep_for(std::chrono::seconds(1));
    EXPECT_FALSE(coco.Exited()) << coco.Stderr();
    coco.Signal(SIGINT);
    coco.Wait(30);
    const std::string writer_err = coco.Stderr();
    const size_t warned = writer_err.find(warning);
    ASSERT_NE(warned, std::string::npos) << writer_err;
    EXPECT_NE(writer_err.find(test.writer_says, warned), std::string::npos) << writer_err;
    EXPECT_EQ(writer_err.find(warning, warned + 1), std::string::npos) << "twice: " << writer_err;
    EXPECT_EQ(writer_err.find("error"), std::string::npos) << writer_err;
    EXPECT_EQ(writer_err.find("no generator heard"), std::string::npos) << writer_err;
    const std::string generator_err = generator.Stderr();
    const size_t at = generator_err.find(test.generator_error);
    ASSERT_NE(at, std::string::npos) << generator_err;
    EXPECT_NE(generator_err.find(test.generator_says, at), std::string::npos) << generator_err;
    EXPECT_EQ(generator_err.find("stackgen: error:", at + 1), std::string::npos) << generator_err;
    EXPECT_TRUE(!std::filesystem::exists(out) || ImagesStored(out) == 0) << out;
  }
}

// One unsigned 22-byte message, what any stranger on the LAN can send, on STACKGEN_CONFIG at a
// writer that waits for its generator and on STACKGEN_CREDIT at a generator that waits for its
// writer's credit (--resume) stops neither: each is still running 3 s later, and the run then
// completes. The writer says what it heard in one warning.
TEST(TrustKeysTest, OneUnsignedDatagramStopsNoOne) {
  const testing::ScratchDir scratch("trust-one");
  const std::string cache = scratch.path() + "/cache";
  const auto coco = [&](const std::string& out, const std::string& url) {
    return std::vector<std::string>{kBin + "/stackgen-coco", "--out", out, "--count", "3",
                                    "--lcm-url", url};
  };
  const auto generator = [&](const std::string& url, std::vector<std::string> extra) {
    std::vector<std::string> argv = {kBin + "/stackgen", "--config", testing::kLandedRule,
                                     "--count", "3", "--seed", "5", "--lcm-url", url,
                                     "--cache-dir", cache, "--consumer-timeout", "30"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return argv;
  };
  const std::vector<uint8_t> noise(22, 0x5A);
  const auto stranger = [&](const std::string& url, const std::string& channel) {
    BusOptions open;
    open.open_bus = true;
    Bus bus(url, open);
    bus.PublishEncoded(channel, noise);
  };

  // a writer waiting for its generator
  {
    const std::string url = testing::FreeMulticastUrl();
    const std::string out = scratch.path() + "/writer-waits";
    Process writer(coco(out, url), out + "-coco");
    ASSERT_TRUE(writer.WaitForOutput("listening", 30)) << writer.Stderr();
    stranger(url, "STACKGEN_CONFIG");
    std::this_thread::sleep_for(std::chrono::seconds(3));
    ASSERT_FALSE(writer.Exited()) << writer.Stderr();
    EXPECT_TRUE(writer.WaitForError("warning: the messages on STACKGEN_SCENE, STACKGEN_CONFIG", 1))
        << writer.Stderr();
    Process gen(generator(url, {}), out + "-gen");
    EXPECT_EQ(gen.Wait(300), 0) << gen.Stderr();
    EXPECT_EQ(writer.Wait(60), 0) << writer.Stderr();
    EXPECT_EQ(ImagesStored(out), 3);
  }
  // a generator waiting for its writer's credit
  {
    const std::string url = testing::FreeMulticastUrl();
    const std::string out = scratch.path() + "/generator-waits";
    Process gen(generator(url, {"--resume"}), out + "-gen");
    std::this_thread::sleep_for(std::chrono::seconds(1));
    stranger(url, "STACKGEN_CREDIT");
    std::this_thread::sleep_for(std::chrono::seconds(3));
    ASSERT_FALSE(gen.Exited()) << gen.Stderr();
    Process writer(coco(out, url), out + "-coco");
    EXPECT_EQ(gen.Wait(300), 0) << gen.Stderr();
    EXPECT_EQ(writer.Wait(60), 0) << writer.Stderr();
    EXPECT_EQ(ImagesStored(out), 3);
  }
}

// A relay between the buses of two runs of one user (one key): every datagram of run B's port
// sent again onto run A's port and back, liveness challenges and answers included, while a
// writer on A waits for its own generator. The writer stores none of B's scenes (with messages
// not bound to their bus it takes them all), says in one warning that what it hears was signed
// for another bus, and counts them relayed; run B completes untouched.
TEST(TrustKeysTest, ARelayFromAnotherBusStoresNothing) {
  const testing::ScratchDir scratch("trust-relay");
  const std::string url_a = testing::FreeMulticastUrl();
  const std::string url_b = testing::FreeMulticastUrl();
  const std::string out_a = scratch.path() + "/a";
  const std::string out_b = scratch.path() + "/b";
  Process writer_a({kBin + "/stackgen-coco", "--out", out_a, "--count", "3", "--lcm-url", url_a},
                   out_a + "-coco");
  ASSERT_TRUE(writer_a.WaitForOutput("listening", 30)) << writer_a.Stderr();

  // the relay: a socket in each group on its port; what one hears goes out to the other (not
  // what the relay itself sent, which it hears back)
  const UdpmAddress a = ParseUdpmUrl(url_a), b = ParseUdpmUrl(url_b);
  const auto listen = [](const UdpmAddress& at) {
    const int fd = socket(AF_INET, SOCK_DGRAM, 0);
    const int yes = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
    sockaddr_in bind_to{};
    bind_to.sin_family = AF_INET;
    bind_to.sin_port = htons(at.port);
    bind_to.sin_addr.s_addr = htonl(at.group);
    EXPECT_EQ(bind(fd, reinterpret_cast<const sockaddr*>(&bind_to), sizeof(bind_to)), 0);
    ip_mreq join{};
    join.imr_multiaddr.s_addr = htonl(at.group);
    join.imr_interface.s_addr = htonl(INADDR_ANY);
    EXPECT_EQ(setsockopt(fd, IPPROTO_IP, IP_ADD_MEMBERSHIP, &join, sizeof(join)), 0);
    return fd;
  };
  const int in_a = listen(a), in_b = listen(b);
  const int out = socket(AF_INET, SOCK_DGRAM, 0);
  const unsigned char ttl = 0;
  setsockopt(out, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl));
  sockaddr_in any{};
  any.sin_family = AF_INET;
  ASSERT_EQ(bind(out, reinterpret_cast<const sockaddr*>(&any), sizeof(any)), 0);
  socklen_t any_length = sizeof(any);
  getsockname(out, reinterpret_cast<sockaddr*>(&any), &any_length);
  const uint16_t own_port = any.sin_port;
  std::atomic<bool> relaying{true};
  std::atomic<int64_t> relayed{0};
  std::thread relay([&] {
    std::vector<uint8_t> buffer(65536);
    while (relaying) {
      pollfd fds[2] = {{in_a, POLLIN, 0}, {in_b, POLLIN, 0}};
      if (poll(fds, 2, 100) <= 0) continue;
      for (int k = 0; k < 2; ++k) {
        if (fds[k].revents == 0) continue;
        sockaddr_in from{};
        socklen_t from_length = sizeof(from);
        const ssize_t size = recvfrom(fds[k].fd, buffer.data(), buffer.size(), 0,
                                      reinterpret_cast<sockaddr*>(&from), &from_length);
        if (size <= 0 || from.sin_port == own_port) continue;
        const UdpmAddress& to_address = k == 0 ? b : a;
        sockaddr_in to{};
        to.sin_family = AF_INET;
        to.sin_port = htons(to_address.port);
        to.sin_addr.s_addr = htonl(to_address.group);
        if (sendto(out, buffer.data(), static_cast<size_t>(size), 0,
                   reinterpret_cast<const sockaddr*>(&to), sizeof(to)) == size) {
          ++relayed;
        }
      }
    }
  });

  Process writer_b({kBin + "/stackgen-coco", "--out", out_b, "--count", "3", "--lcm-url", url_b},
                   out_b + "-coco");
  EXPECT_TRUE(writer_b.WaitForOutput("listening", 30)) << writer_b.Stderr();
  Process generator_b({kBin + "/stackgen", "--config", testing::kLandedRule, "--count", "3",
                       "--seed", "7", "--lcm-url", url_b, "--cache-dir",
                       scratch.path() + "/cache"},
                      out_b + "-gen");
  EXPECT_EQ(generator_b.Wait(300), 0) << generator_b.Stderr();
  EXPECT_EQ(writer_b.Wait(60), 0) << writer_b.Stderr();
  std::this_thread::sleep_for(std::chrono::seconds(1));
  relaying = false;
  relay.join();
  for (const int fd : {in_a, in_b, out}) close(fd);
  EXPECT_GT(relayed.load(), 10);
  EXPECT_EQ(ImagesStored(out_b), 3);

  EXPECT_FALSE(writer_a.Exited()) << writer_a.Stderr();
  // its status, heard on its own bus, counts them too (refused_relayed)
  {
    Bus listener(url_a);
    int64_t in_status = -1;
    listener.Subscribe<status>(kStatusChannel, [&in_status](const status& message) {
      if (message.process == "stackgen-coco") in_status = message.refused_relayed;
    });
    for (int i = 0; i < 100 && in_status <= 0; ++i) listener.HandleFor(50);
    EXPECT_GT(in_status, 0) << "no status of the writer counting relayed messages";
  }
  writer_a.Signal(SIGINT);
  writer_a.Wait(30);
  EXPECT_TRUE(!std::filesystem::exists(out_a) || ImagesStored(out_a) == 0) << writer_a.Stderr();
  const std::string err = writer_a.Stderr();
  EXPECT_NE(err.find("for another bus (group and port): relayed"), std::string::npos) << err;
  const std::string text = writer_a.Stdout() + err;
  const std::regex counted(R"((\d+) relayed from another bus)");
  std::smatch match;
  ASSERT_TRUE(std::regex_search(text, match, counted)) << text;
  EXPECT_GT(std::stoll(match[1]), 0) << text;
}

}  // namespace
}  // namespace stackgen
