// No datagram can crash a process (docs/design.md, "Trust"): stackgen, stackgen-coco, stackgen-bop and
// a Python stackgen.Stream share a keyed bus while stackgen-forger (tests/e2e/forger.cc) sends
// raw datagrams in LCM's wire format that no LCM library sends: the two datagrams that make
// liblcm 1.3.1 write 4 GB past a buffer (lcm-proj/lcm#628), on every channel, and 50,000
// mutations of real recorded messages. Every process finishes, its memory stays near a clean
// run's, and every dataset (and what the stream handed out) equals the clean run's.

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/datasets.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::Process;

constexpr int kScenes = 8;
const std::string kBin = STACKGEN_BIN_DIR;
const std::string kForger = std::string(STACKGEN_TEST_BIN_DIR) + "/stackgen-forger";
const std::string kFixtureLog =
    std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog";

// a reliable stackgen.Stream that prints a digest of every scene it hands out, then its counters
constexpr const char* kStreamScript = R"(
import hashlib, sys
import stackgen
url, count = sys.argv[1], int(sys.argv[2])
with stackgen.Stream(lcm_url=url, count=count, timeout=300, depth=True) as stream:
    print("listening", flush=True)
    for scene in stream:
        digest = hashlib.sha256()
        for array in (scene.color, scene.depth, scene.instance_map, scene.camera_from_object,
                      scene.bbox_visib, scene.visib_fract):
            digest.update(array.tobytes())
        print("scene %d %d %s" % (scene.generator_id, scene.seq, digest.hexdigest()), flush=True)
    print("counters", sorted(stream.counters.items()), flush=True)
)";

// the peak resident memory of a process so far, kB (VmHWM; 0 once it is gone)
int64_t PeakKb(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stoll(line.substr(6));
  }
  return 0;
}

// what one run left: the datasets, the stream's scene lines, each process's peak memory
struct RunOutputs {
  std::string coco;
  std::string bop;
  std::vector<std::string> stream_scenes;
  std::map<std::string, int64_t> peak_kb;
  std::map<std::string, std::string> stdout_of;
};

class DatagramFuzzTest : public ::testing::Test {
 protected:
  // the clean run, made once for the file's tests (CTest runs them in one process)
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir("datagram-fuzz");
    ASSERT_NE(std::getenv("STACKGEN_BUS_KEY_FILE"), nullptr)
        << "the suite runs with a bus key (tests/CMakeLists.txt); run this through ctest";
    std::ofstream(scratch_->path() + "/stream.py") << kStreamScript;
    RunAll("clean", {}, false, &clean_);
  }

  static void TearDownTestSuite() {
    delete scratch_;
    scratch_ = nullptr;
  }

  // the four processes on a bus of their own, and the forger with `forger_flags` when given
  // (stopped with SIGINT once they are done when `stop_forger`, else waited for)
  static void RunAll(const std::string& name, const std::vector<std::string>& forger_flags,
              bool stop_forger, RunOutputs* run) {
    const std::string url = testing::FreeMulticastUrl();
    const std::string base = scratch_->path() + "/" + name;
    run->coco = base + "-coco";
    run->bop = base + "-bop";
    Process coco({kBin + "/stackgen-coco", "--out", run->coco, "--count", std::to_string(kScenes),
                  "--lcm-url", url},
                 base + "-coco-log");
    Process bop({kBin + "/stackgen-bop", "--out", run->bop, "--count", std::to_string(kScenes),
                 "--lcm-url", url},
                base + "-bop-log");
    const testing::ScopedEnv python_path("PYTHONPATH", STACKGEN_PYTHON_DIR);
    Process stream({STACKGEN_PYTHON, scratch_->path() + "/stream.py", url, std::to_string(kScenes)},
                   base + "-stream");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    ASSERT_TRUE(bop.WaitForOutput("listening", 30)) << bop.Stderr();
    ASSERT_TRUE(stream.WaitForOutput("listening", 60)) << stream.Stderr();
    Process generator({kBin + "/stackgen", "--config", testing::kLandedRule, "--count",
                       std::to_string(kScenes), "--seed", "3", "--lcm-url", url, "--cache-dir",
                       scratch_->path() + "/cache", "--consumer-timeout", "20"},
                      base + "-gen");
    // the forger once all four listen (the generator says so when its bus and renderer are
    // up, then listens 0.5 s before its first scene): every datagram reaches every process
    std::unique_ptr<Process> forger;
    if (!forger_flags.empty()) {
      ASSERT_TRUE(generator.WaitForOutput("stackgen: generator", 60)) << generator.Stderr();
      std::vector<std::string> argv = {kForger, "--lcm-url", url, "--no-attacks"};
      argv.insert(argv.end(), forger_flags.begin(), forger_flags.end());
      forger = std::make_unique<Process>(argv, base + "-forger");
    }
    // the peak memory of each while the generator runs, then the others' to their end
    std::vector<std::pair<std::string, Process*>> all = {{"stackgen", &generator},
                                                         {"stackgen-coco", &coco},
                                                         {"stackgen-bop", &bop},
                                                         {"stackgen.Stream", &stream}};
    for (int i = 0; i < 12000; ++i) {
      bool running = false;
      for (const auto& [what, process] : all) {
        if (process->Exited()) continue;
        running = true;
        run->peak_kb[what] = std::max(run->peak_kb[what], PeakKb(process->pid()));
      }
      if (!running) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    EXPECT_EQ(generator.Wait(60), 0) << generator.Stderr();
    EXPECT_EQ(coco.Wait(60), 0) << coco.Stderr();
    EXPECT_EQ(bop.Wait(60), 0) << bop.Stderr();
    EXPECT_EQ(stream.Wait(60), 0) << stream.Stderr();
    if (forger) {
      if (stop_forger) forger->Signal(SIGINT);
      EXPECT_EQ(forger->Wait(60), 0) << forger->Stderr();
      run->stdout_of["stackgen-forger"] = forger->Stdout();
    }
    for (const auto& [what, process] : all) run->stdout_of[what] = process->Stdout();
    const std::regex scene_line(R"(scene \d+ \d+ [0-9a-f]{64})");
    std::istringstream lines(stream.Stdout());
    for (std::string line; std::getline(lines, line);) {
      if (std::regex_match(line, scene_line)) run->stream_scenes.push_back(line);
    }
  }

  // every output of `run` equals the clean run's; prints and checks each process's peak memory
  void ExpectAsClean(const RunOutputs& run) {
    testing::ExpectSameDataset(clean_.coco, run.coco, kScenes);
    const auto clean_files = testing::DatasetFiles(clean_.bop, "bop.journal");
    const auto files = testing::DatasetFiles(run.bop, "bop.journal");
    EXPECT_EQ(files.size(), clean_files.size());
    for (const auto& [path, bytes] : clean_files) {
      const auto found = files.find(path);
      ASSERT_NE(found, files.end()) << path << " is missing from " << run.bop;
      EXPECT_TRUE(found->second == bytes) << path << " differs from the clean run's";
    }
    std::vector<std::string> clean_scenes = clean_.stream_scenes, scenes = run.stream_scenes;
    std::sort(clean_scenes.begin(), clean_scenes.end());
    std::sort(scenes.begin(), scenes.end());
    EXPECT_EQ(clean_scenes.size(), static_cast<size_t>(kScenes));
    EXPECT_EQ(scenes, clean_scenes);
    for (const auto& [what, clean_kb] : clean_.peak_kb) {
      const int64_t kb = run.peak_kb.at(what);
      std::printf("peak resident memory of %s: clean %lld kB, attacked %lld kB\n", what.c_str(),
                  static_cast<long long>(clean_kb), static_cast<long long>(kb));
      // bounded: within 64 MB of the clean run's (a scene is about 1 MB encoded)
      EXPECT_LT(kb, clean_kb + 65536) << what;
    }
  }

  static testing::ScratchDir* scratch_;
  static RunOutputs clean_;
};

testing::ScratchDir* DatagramFuzzTest::scratch_ = nullptr;
RunOutputs DatagramFuzzTest::clean_;

// The two datagrams of lcm#628 on every channel, every 20 ms through the whole run: stackgen
// (credits, resends, status), the writers (scenes, config, models) and the stream (scenes) each
// finish as in the clean run.
TEST_F(DatagramFuzzTest, TwoDatagramsOfLcm628OnEveryChannel) {
  RunOutputs attacked;
  RunAll("lcm628", {"--seconds", "600", "--lcm628"}, true, &attacked);
  ExpectAsClean(attacked);
  const std::string& forger = attacked.stdout_of["stackgen-forger"];
  std::printf("%s", forger.c_str());
  EXPECT_EQ(forger.find("(0 pairs"), std::string::npos) << forger;
}

// 50,000 raw datagrams made from real recorded messages (the fixture log's scenes, labels and
// config, and what the forger hears), cut into LC02/LC03 datagrams and mutated, from a fixed
// seed, spread over the run: every process finishes as in the clean run, memory bounded.
TEST_F(DatagramFuzzTest, FiftyThousandMutatedDatagrams) {
  RunOutputs fuzzed;
  // spread over 1 s of the generator's run (its first scene comes 0.5 s after it listens, and
  // 8 scenes take seconds more), so every datagram reaches every process
  RunAll("fuzzed", {"--seconds", "1", "--datagrams", "50000", "--samples", kFixtureLog}, false,
         &fuzzed);
  ExpectAsClean(fuzzed);
  const std::string& forger = fuzzed.stdout_of["stackgen-forger"];
  std::printf("%s", forger.c_str());
  EXPECT_NE(forger.find("50000 raw datagrams"), std::string::npos) << forger;
  // what the receivers made of them: most malformed, counted
  for (const std::string program : {"stackgen", "stackgen-coco", "stackgen-bop"}) {
    const std::string& out = fuzzed.stdout_of[program];
    const std::regex counts(program + R"(: received (\d+) datagrams: (\d+) malformed, (\d+) )"
                                      R"(messages given up incomplete)");
    std::smatch match;
    ASSERT_TRUE(std::regex_search(out, match, counts)) << out;
    std::printf("%s: %s datagrams received, %s malformed, %s messages given up\n", program.c_str(),
                match[1].str().c_str(), match[2].str().c_str(), match[3].str().c_str());
    EXPECT_GT(std::stoll(match[2].str()), 1000) << out;
  }
}

}  // namespace
}  // namespace stackgen
