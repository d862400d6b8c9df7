// Runs the stackgen-coco program as a process: its command line, and scenes sent to it over real
// UDP multicast on this host.

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <stackgen/header.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "tests/consumers/coco/coco_test_scenes.h"
#include "tests/support/live_bus.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::Process;

const std::string kProgram = std::string(STACKGEN_BIN_DIR) + "/stackgen-coco";

// runs stackgen-coco with `args` to the end; returns its exit code
int RunToEnd(const std::vector<std::string>& args, const std::string& log_prefix, std::string* out,
             std::string* err) {
  return testing::RunToEnd(kProgram, args, log_prefix, out, err, 30);
}

// --help documents every flag and its default, and exits 0.
TEST(CocoMainTest, HelpListsEveryFlag) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  std::string out, err;
  EXPECT_EQ(RunToEnd({"--help"}, dir + "/help", &out, &err), 0);
  for (const char* text : {"--out", "--count", "--lcm-url", "--min-visib-fract", "--group-commit",
                           "--help", "default 0", "follow the generator", "iscrowd 1",
                           "amodal_segmentation", "STACKGEN_LCM_URL"}) {
    EXPECT_NE(out.find(text), std::string::npos) << text << " missing from\n" << out;
  }
}

// Bad numbers and unknown flags give one line on stderr and exit 2.
TEST(CocoMainTest, BadCommandLineExits2) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--out", dir + "/a", "--count", "-3"},
        {"--out", dir + "/a", "--count", "12x"},
        {"--out", dir + "/a", "--count", "many"},
        {"--out", dir + "/a", "--min-visib-fract", "1.5"},
        {"--out", dir + "/a", "--bogus"},
        {"--count", "3"}}) {
    std::string out, err;
    EXPECT_EQ(RunToEnd(args, dir + "/bad", &out, &err), 2) << args.back();
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_EQ(err.rfind("stackgen-coco: error: ", 0), 0u) << err;
  }
  EXPECT_FALSE(fs::exists(dir + "/a"));
}

// A folder that holds a dataset is refused with one error line and exit 1.
TEST(CocoMainTest, RefusesExistingDataset) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  { std::ofstream(dir + "/annotations.json") << "{}"; }
  std::string out, err;
  EXPECT_EQ(
      RunToEnd({"--out", dir, "--lcm-url", testing::FreeMulticastUrl()}, dir + "/run", &out, &err),
      1);
  EXPECT_EQ(err.rfind("stackgen-coco: error: ", 0), 0u) << err;
  EXPECT_NE(err.find("annotations.json"), std::string::npos) << err;
  EXPECT_EQ(testing::ReadFile(dir + "/annotations.json"), "{}");
}

// A BOP dataset's folder is named as one, with or without --resume: stackgen-coco never writes
// into another writer's dataset.
TEST(CocoMainTest, RefusesABopDataset) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  { std::ofstream(dir + "/bop.journal") << ""; }
  for (const bool resume : {false, true}) {
    std::vector<std::string> args = {"--out", dir, "--lcm-url", testing::FreeMulticastUrl()};
    if (resume) args.push_back("--resume");
    std::string out, err;
    EXPECT_EQ(RunToEnd(args, dir + "/run", &out, &err), 1);
    EXPECT_NE(err.find(dir +
                       " holds a stackgen-bop dataset (bop.journal), not a stackgen-coco "
                       "one: " +
                       (resume ? "resume it with stackgen-bop"
                               : "write into an empty or new --out folder")),
              std::string::npos)
        << err;
    EXPECT_EQ(testing::ReadFile(dir + "/bop.journal"), "");
  }
}

// A bus or log that cannot be opened, and a journal that is not one, get one line naming the
// URL or the journal line, exit 1, and leave nothing behind: no dataset folder, no images/, the
// journal as it was.
TEST(CocoMainTest, BadBusOrJournalLeavesNothing) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  { std::ofstream(dir + "/junk.log") << "not an LCM log"; }
  for (const auto& [url, why] : std::vector<std::pair<std::string, std::string>>{
           {"bogus://x", "LCM provider \"bogus\" not found"},
           {"file://" + dir + "/missing.log?speed=0", "No such file or directory"},
           {"file://" + dir + "/junk.log?speed=0", "Failed to read first event from log"}}) {
    std::string out, err;
    EXPECT_EQ(RunToEnd({"--out", dir + "/out", "--lcm-url", url}, dir + "/run", &out, &err), 1);
    EXPECT_EQ(err, "stackgen-coco: error: cannot open the LCM bus at " + url + ": " +
                       (why == "No such file or directory"
                            ? "Failed to open " + dir + "/missing.log: " + why
                            : why) +
                       "\n");
    EXPECT_FALSE(fs::exists(dir + "/out")) << url;
  }
  fs::create_directory(dir + "/damaged");
  { std::ofstream(dir + "/damaged/annotations.journal") << "garbage\n"; }
  std::string out, err;
  EXPECT_EQ(RunToEnd({"--out", dir + "/damaged", "--resume", "--lcm-url",
                      "file://" + dir + "/junk.log?speed=0"},
                     dir + "/run", &out, &err),
            1);
  EXPECT_EQ(
      RunToEnd({"--out", dir + "/damaged", "--resume", "--lcm-url", testing::FreeMulticastUrl()},
               dir + "/run", &out, &err),
      1);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_NE(err.find(dir + "/damaged/annotations.journal line 1 (byte 0): not a journal record"),
            std::string::npos)
      << err;
  EXPECT_FALSE(fs::exists(dir + "/damaged/images"));
  EXPECT_EQ(testing::ReadFile(dir + "/damaged/annotations.journal"), "garbage\n");
}

// Scenes over multicast: a repeat is stored once, an undecodable message is skipped, a seq gap
// that no generator fills is counted as missing and lost, and the program stops after --count
// scenes with a summary line.
TEST(CocoMainTest, StoresScenesFromTheBus) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  const std::string url = testing::FreeMulticastUrl();
  Process coco({kProgram, "--out", dir + "/coco", "--count", "3", "--lcm-url", url}, dir + "/run");
  ASSERT_TRUE(coco.WaitForOutput("listening on " + url + " channel STACKGEN_SCENE", 30))
      << coco.Stderr();

  Bus bus(url);
  ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-coco never answered";
  const auto send = [&bus](const auto& message) {
    bus.Publish(kSceneChannel, message);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  };
  stackgen::header not_a_scene{};
  send(testing::SceneA());
  send(testing::SceneA());
  send(not_a_scene);
  send(testing::SceneB());
  send(testing::MakeScene(0, 3, {}));  // seq 2 never comes

  ASSERT_EQ(coco.Wait(30), 0) << coco.Stderr();
  EXPECT_NE(coco.Stdout().find("stackgen-coco: wrote " + dir +
                               "/coco/annotations.json: 3 images, 3 annotations, 0 ignore "
                               "regions (iscrowd 1), 1 dropped (not annotated), 1 lost"),
            std::string::npos)
      << coco.Stdout();
  EXPECT_NE(coco.Stdout().find("delivery: 4 scenes received, 3 stored, 1 received twice"),
            std::string::npos)
      << coco.Stdout();
  EXPECT_NE(coco.Stdout().find(", 1 missing"), std::string::npos) << coco.Stdout();
  EXPECT_NE(coco.Stderr().find("1 undecodable"), std::string::npos) << coco.Stderr();
  const json dataset = json::parse(testing::ReadFile(dir + "/coco/annotations.json"));
  EXPECT_EQ(dataset["images"].size(), 3u);
  EXPECT_EQ(dataset["annotations"].size(), 3u);
  // the journal stays: the durable record a --resume continues from
  EXPECT_TRUE(fs::exists(dir + "/coco/annotations.journal"));
}

// A damaged copy of a scene (one bit flipped in its PNG, as a stranger or a bad link could send
// it) is refused and counted, and does not count as received: the writer asks for that seq
// again once the next one arrives, and stores the intact copy.
TEST(CocoMainTest, DamagedCopyIsRefusedAndAskedForAgain) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  const std::string url = testing::FreeMulticastUrl();
  Process coco({kProgram, "--out", dir + "/coco", "--count", "2", "--lcm-url", url}, dir + "/run");
  ASSERT_TRUE(coco.WaitForOutput("listening on " + url, 30)) << coco.Stderr();

  Bus bus(url);
  ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-coco never answered";
  bool asked_again = false;
  bus.Subscribe<resend_request>(kResendChannel, [&](const resend_request& request) {
    for (int64_t seq : request.seqs) asked_again = asked_again || seq == 0;
  });
  const stackgen::scene intact = testing::SceneB();  // generator 0, seq 1, a PNG
  ASSERT_EQ(intact.color.encoding, stackgen::image::ENCODING_PNG);
  stackgen::scene first = intact, damaged = intact;
  first.header.seq = 0;
  damaged.header.seq = 0;
  damaged.color.data[damaged.color.data.size() / 2] ^= 0x10;
  bus.Publish(kSceneChannel, damaged);
  bus.HandleFor(100);
  bus.Publish(kSceneChannel, intact);
  for (int i = 0; i < 50 && !asked_again; ++i) bus.HandleFor(100);
  EXPECT_TRUE(asked_again) << "seq 0 was not asked for again";
  bus.Publish(kSceneChannel, first);

  ASSERT_EQ(coco.Wait(30), 0) << coco.Stderr();
  EXPECT_NE(coco.Stderr().find("refused a scene: scene 0/0: color.data does not decode as a "
                               "whole PNG image"),
            std::string::npos)
      << coco.Stderr();
  EXPECT_NE(coco.Stderr().find("refused 1 invalid scenes"), std::string::npos) << coco.Stderr();
  EXPECT_NE(coco.Stdout().find("2 stored"), std::string::npos) << coco.Stdout();
  const std::string stored = testing::ReadFile(dir + "/coco/images/0_000000.png");
  EXPECT_EQ(std::vector<uint8_t>(stored.begin(), stored.end()), first.color.data)
      << "the stored image is not the intact copy";
}

// A writer that hears no generator says so after --warn-silent seconds, naming the URL and the
// bus key to check, and goes on waiting.
TEST(CocoMainTest, SaysSoWhenNoGeneratorIsHeard) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  const std::string url = testing::FreeMulticastUrl();
  Process coco({kProgram, "--out", dir + "/coco", "--lcm-url", url, "--warn-silent", "1"},
               dir + "/run");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  for (int i = 0; i < 100 && coco.Stderr().find("no generator") == std::string::npos; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  const std::string err = coco.Stderr();
  EXPECT_NE(err.find("stackgen-coco: no generator heard for 1 s on " + url), std::string::npos)
      << err;
  EXPECT_NE(err.find("(the same port) and the bus key "), std::string::npos) << err;
  EXPECT_NE(err.find("still waiting"), std::string::npos) << err;
  coco.Signal(SIGINT);
  EXPECT_EQ(coco.Wait(30), 0) << coco.Stderr();
}

// A writer whose generator says it stopped before its end (its last status: a signal, a stall)
// says so at once, with what it now waits for, rather than waiting without a word; the same
// status again is not said twice.
TEST(CocoMainTest, SaysSoWhenItsGeneratorStopsBeforeItsEnd) {
  const testing::ScopedTempDir scratch("coco-main");
  const std::string dir = scratch.path();
  const std::string url = testing::FreeMulticastUrl();
  Process coco({kProgram, "--out", dir + "/coco", "--count", "5", "--lcm-url", url},
               dir + "/run");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Bus bus(url);
  ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-coco never answered";
  stackgen::status stopped{};
  stopped.header.seq = -1;
  stopped.header.generator_id = 0;
  stopped.next_seq = 2;
  stopped.process = "stackgen";
  stopped.name = "stackgen/0@test:1";
  stopped.run_state = kRunStopped;
  // (again until heard: the writer takes this bus's messages once it has heard it answer its
  // own liveness challenge, which may come a moment after this bus heard the writer's answer)
  bool said = false;
  for (int k = 0; k < 50 && !said; ++k) {
    bus.Publish(kStatusChannel, stopped);
    said = coco.WaitForError("generator 0 (stackgen/0@test:1) stopped before its end", 0.2);
  }
  ASSERT_TRUE(said) << coco.Stderr();
  const std::string err = coco.Stderr();
  EXPECT_NE(err.find("0 of 5 scenes stored: waiting for a generator to continue the run "
                     "(stackgen --resume"),
            std::string::npos)
      << err;
  coco.Signal(SIGINT);
  EXPECT_EQ(coco.Wait(30), 0) << coco.Stderr();
  const std::string all = coco.Stderr();
  EXPECT_EQ(all.find("stopped before its end"), all.rfind("stopped before its end")) << all;
}

// SIGINT and SIGTERM finish a valid dataset of what arrived; --min-visib-fract drops annotated
// instances below it and keeps ignore regions.
TEST(CocoMainTest, SignalFinishesDataset) {
  for (const int signal_number : {SIGINT, SIGTERM}) {
    const testing::ScopedTempDir scratch("coco-main");
    const std::string dir = scratch.path();
    const std::string url = testing::FreeMulticastUrl();
    Process coco({kProgram, "--out", dir + "/coco", "--lcm-url", url, "--min-visib-fract", "0.5"},
                 dir + "/run");
    ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
    Bus bus(url);
    ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-coco never answered";
    bus.Publish(kSceneChannel, testing::SceneA());
    bus.Publish(kSceneChannel, testing::SceneD());
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    EXPECT_FALSE(fs::exists(dir + "/coco/annotations.json"));
    coco.Signal(signal_number);
    ASSERT_EQ(coco.Wait(30), 0) << coco.Stderr();
    // A: 1 and 3 kept, 2 not annotated; D: 1 kept, 2 an ignore region, 3 not annotated
    EXPECT_NE(coco.Stdout().find("2 images, 3 annotations, 1 ignore regions (iscrowd 1), 2 "
                                 "dropped (not annotated, or visib_fract < 0.5), 0 lost"),
              std::string::npos)
        << coco.Stdout();
    const json dataset = json::parse(testing::ReadFile(dir + "/coco/annotations.json"));
    EXPECT_EQ(dataset["images"].size(), 2u);
    ASSERT_EQ(dataset["annotations"].size(), 4u);
    EXPECT_EQ(dataset["annotations"][3]["iscrowd"], 1);
  }
}

}  // namespace
}  // namespace stackgen
