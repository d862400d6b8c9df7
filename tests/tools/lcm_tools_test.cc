// The stock LCM tools on stackgen's channels, run as processes: tools/spy --check (lcm-spy's own
// type lookup on the Java types jar, and lcm-spy's decoding of logged messages) and tools/record
// (lcm-logger on a private multicast port).

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/config_text.hpp>
#include <stackgen/credit.hpp>
#include <stackgen/labels.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/log.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using testing::FindOnPath;
using testing::Process;
using testing::ScratchDir;

const std::string kRoot = STACKGEN_SOURCE_DIR;
const std::string kSpy = kRoot + "/tools/spy";
const std::string kRecord = kRoot + "/tools/record";
const std::string kForger = std::string(STACKGEN_TEST_BIN_DIR) + "/stackgen-forger";
// the build under test: tools/spy finds the types jar in its share/
const std::string kBuildDir = fs::path(STACKGEN_BIN_DIR).parent_path().string();
const std::string kTypesJar = kBuildDir + "/share/stackgen_types.jar";
const std::string kFixtureLog = kRoot + "/tests/fixtures/logs/tiny.lcmlog";

// why tools/spy --check cannot run here; empty when it can
std::string SpyCheckUnavailable() {
  if (FindOnPath("java").empty()) return "java is not installed (tools/install-deps)";
  if (!fs::exists("/usr/share/java/lcm.jar")) return "no /usr/share/java/lcm.jar (liblcm-java)";
  if (!fs::exists(kTypesJar)) return "no " + kTypesJar + " (cmake found no JDK)";
  return "";
}

// every type types/*.lcm defines, as package.struct
std::set<std::string> TypesOfLcmFiles() {
  std::set<std::string> types;
  const std::regex package_line(R"(^\s*package\s+([A-Za-z0-9_.]+)\s*;)");
  const std::regex struct_line(R"(^\s*struct\s+([A-Za-z0-9_]+))");
  for (const auto& entry : fs::directory_iterator(kRoot + "/types")) {
    if (entry.path().extension() != ".lcm") continue;
    std::ifstream file(entry.path());
    std::string line, package;
    std::smatch match;
    while (std::getline(file, line)) {
      if (std::regex_search(line, match, package_line)) package = match[1].str() + ".";
      if (std::regex_search(line, match, struct_line)) types.insert(package + match[1].str());
    }
  }
  return types;
}

// runs tools/spy with `args` against the jar of `build_dir`; returns its exit code
int RunSpy(const std::vector<std::string>& args, const std::string& build_dir,
           const std::string& log_prefix, std::string* out, std::string* err) {
  setenv("STACKGEN_BUILD_DIR", build_dir.c_str(), 1);
  std::vector<std::string> argv = {kSpy};
  argv.insert(argv.end(), args.begin(), args.end());
  Process spy(argv, log_prefix);
  const int code = spy.Wait(120);
  unsetenv("STACKGEN_BUILD_DIR");
  *out = spy.Stdout();
  *err = spy.Stderr();
  return code;
}

// "0x" and the 16 hex digits of an LCM fingerprint
std::string Hex(int64_t fingerprint) {
  char text[24];
  std::snprintf(text, sizeof(text), "0x%016llx",
                static_cast<unsigned long long>(static_cast<uint64_t>(fingerprint)));
  return text;
}

// tools/spy --check finds every type of types/*.lcm in the jar through lcm-spy's type lookup and
// prints it with its fingerprint, the same one the C++ code has.
TEST(LcmToolsTest, SpyCheckListsEveryType) {
  const std::string unavailable = SpyCheckUnavailable();
  if (!unavailable.empty()) GTEST_SKIP() << unavailable;
  const ScratchDir scratch("lcm-tools");
  std::string out, err;
  ASSERT_EQ(RunSpy({"--check"}, kBuildDir, scratch.path() + "/spy", &out, &err), 0) << out << err;

  const std::set<std::string> types = TypesOfLcmFiles();
  ASSERT_FALSE(types.empty());
  for (const std::string& type : types) {
    const std::regex line("(^|\n)" + std::regex_replace(type, std::regex(R"(\.)"), R"(\.)") +
                          " 0x[0-9a-f]{16}(\n|$)");
    EXPECT_TRUE(std::regex_search(out, line)) << type << " missing from\n" << out;
  }
  // the Java classes and the C++ ones come from the same definitions
  for (const auto& [name, hash] :
       std::map<std::string, int64_t>{{"stackgen.scene", scene::getHash()},
                                      {"stackgen.labels", labels::getHash()},
                                      {"stackgen.status", status::getHash()},
                                      {"stackgen.config_text", config_text::getHash()},
                                      {"stackgen.credit", credit::getHash()},
                                      {"stackgen.resend_request", resend_request::getHash()}}) {
    EXPECT_NE(out.find(name + " " + Hex(hash) + "\n"), std::string::npos)
        << name << " " << Hex(hash) << " missing from\n"
        << out;
  }
}

// lcm-spy decodes a message of every channel: the recorded scenes, labels and configs of the
// fixture log, and status, credit and resend messages written here with today's types.
TEST(LcmToolsTest, SpyCheckDecodesEveryChannel) {
  const std::string unavailable = SpyCheckUnavailable();
  if (!unavailable.empty()) GTEST_SKIP() << unavailable;
  const ScratchDir scratch("lcm-tools");
  const std::string log = scratch.path() + "/channels.lcmlog";
  {
    LogWriter writer(log);
    status status_message{};
    status_message.process = "stackgen";
    writer.Write(kStatusChannel, status_message, 1);
    credit credit_message{};
    credit_message.consumer = "test";
    writer.Write(kCreditChannel, credit_message, 2);
    resend_request resend_message{};
    resend_message.consumer = "test";
    resend_message.num_seqs = 2;
    resend_message.seqs = {3, 4};
    writer.Write(kResendChannel, resend_message, 3);
  }
  std::string out, err;
  ASSERT_EQ(RunSpy({"--check", kFixtureLog, log}, kBuildDir, scratch.path() + "/spy", &out, &err),
            0)
      << out << err;
  for (const std::string& line :
       {kFixtureLog + ": STACKGEN_SCENE 4 events decode as stackgen.scene",
        kFixtureLog + ": STACKGEN_LABELS 4 events decode as stackgen.labels",
        log + ": STACKGEN_STATUS 1 events decode as stackgen.status",
        log + ": STACKGEN_CREDIT 1 events decode as stackgen.credit",
        log + ": STACKGEN_RESEND 1 events decode as stackgen.resend_request"}) {
    EXPECT_NE(out.find(line + "\n"), std::string::npos) << line << " missing from\n" << out << err;
  }
  EXPECT_TRUE(std::regex_search(
      out, std::regex(": STACKGEN_CONFIG [0-9]+ events decode as stackgen\\.config_text\n")))
      << out;
}

// tools/spy --check fails, naming the type, when the jar lacks a type of types/*.lcm.
TEST(LcmToolsTest, SpyCheckFailsOnMissingType) {
  const std::string unavailable = SpyCheckUnavailable();
  if (!unavailable.empty()) GTEST_SKIP() << unavailable;
  const std::string jar_tool = FindOnPath("jar");
  if (jar_tool.empty()) GTEST_SKIP() << "no jar tool (a JDK: default-jdk-headless)";
  const ScratchDir scratch("lcm-tools");
  // a copy of the jar without stackgen/labels.class, in a build folder of its own
  const std::string classes = scratch.path() + "/classes";
  fs::create_directories(classes);
  fs::create_directories(scratch.path() + "/build/share");
  const std::string command = "cd '" + classes + "' && '" + jar_tool + "' xf '" + kTypesJar +
                              "' && rm stackgen/labels.class && '" + jar_tool + "' cf '" +
                              scratch.path() + "/build/share/stackgen_types.jar' -C . stackgen";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;

  std::string out, err;
  EXPECT_NE(RunSpy({"--check"}, scratch.path() + "/build", scratch.path() + "/spy", &out, &err), 0)
      << out;
  EXPECT_NE(err.find("stackgen.labels (types/*.lcm) is missing from"), std::string::npos) << err;
  EXPECT_NE(out.find("stackgen.scene 0x"), std::string::npos) << out;
}

// tools/record on a private port records what is published on stackgen's channels and nothing
// else, stops cleanly on SIGINT, and the log reads back with every message it heard; the two
// datagrams of lcm#628 on every channel every 20 ms (stackgen-forger --lcm628), which make
// liblcm's receiver (lcm-logger's) write past a buffer, change nothing of that.
TEST(LcmToolsTest, RecordWritesOnlyStackgenChannels) {
  const ScratchDir scratch("lcm-tools");
  const std::string url = testing::FreeMulticastUrl();
  const std::string log = scratch.path() + "/run.lcmlog";
  Process record({kRecord, "--lcm-url", url, "--out", log}, scratch.path() + "/record");
  ASSERT_TRUE(record.WaitForOutput("Ctrl-C stops", 30)) << record.Stderr();

  // a config until the logger has written something: it is listening then
  Bus bus(url);
  config_text config{};
  config.path = "probe.pbtxt";
  struct stat info {};
  const std::string part = log + ".part";  // the log until the recorder stops
  for (int i = 0; i < 200 && (stat(part.c_str(), &info) != 0 || info.st_size == 0); ++i) {
    bus.Publish(kConfigChannel, config);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_GT(info.st_size, 0) << "the recorder wrote nothing: " << record.Stdout()
                             << record.Stderr();
  Process forger({kForger, "--lcm-url", url, "--lcm628", "--no-attacks", "--seconds", "3"},
                 scratch.path() + "/forger");
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));

  // labels 0..4, mixed with messages on channels it must not record
  for (int seq = 0; seq < 5; ++seq) {
    labels message{};
    message.header.seq = seq;
    message.header.generator_id = 7;
    bus.Publish(kLabelsChannel, message);
    bus.Publish("STACKGEN_LABELS_COPY", message);
    bus.Publish("OTHER_LABELS", message);
    bus.Publish(kCreditChannel, credit{});
  }
  ASSERT_EQ(forger.Wait(60), 0) << forger.Stderr();
  EXPECT_NE(forger.Stdout().find("pairs of lcm#628"), std::string::npos) << forger.Stdout();
  EXPECT_EQ(forger.Stdout().find("(0 pairs of lcm#628)"), std::string::npos) << forger.Stdout();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  record.Signal(SIGINT);
  ASSERT_EQ(record.Wait(30), 0) << record.Stdout() << record.Stderr();
  EXPECT_NE(record.Stdout().find("tools/record: wrote " + log), std::string::npos)
      << record.Stdout();
  EXPECT_NE(record.Stdout().find("lcm-logplayer --lcm-url"), std::string::npos) << record.Stdout();
  EXPECT_NE(record.Stdout().find("file://" + log + "?speed=0"), std::string::npos)
      << record.Stdout();

  std::map<std::string, int> events;  // per channel
  std::vector<int64_t> label_seqs;
  const LogSummary summary = ReadLog(log, [&](const LogEvent& event) {
    ++events[event.channel];
    if (event.channel == kLabelsChannel) {
      const labels message = DecodeLogEvent<labels>(event);
      EXPECT_EQ(message.header.generator_id, 7);
      label_seqs.push_back(message.header.seq);
    } else if (event.channel == kConfigChannel) {
      EXPECT_EQ(DecodeLogEvent<config_text>(event).path, "probe.pbtxt");
    }
  });
  EXPECT_EQ(summary.truncated_bytes, 0);
  EXPECT_EQ(label_seqs, (std::vector<int64_t>{0, 1, 2, 3, 4}));
  EXPECT_GE(events[kConfigChannel], 1);
  events.erase(kConfigChannel);
  events.erase(kLabelsChannel);
  EXPECT_TRUE(events.empty()) << "recorded another channel: " << events.begin()->first;
}

// --channels that is not a regular expression is one line and exit 2 at once (lcm-logger would
// print GLib's error and record nothing until stopped), and no log is made.
TEST(LcmToolsTest, RecordRefusesABadRegex) {
  const ScratchDir scratch("lcm-tools");
  const std::string log = scratch.path() + "/run.lcmlog";
  Process record(
      {kRecord, "--lcm-url", testing::FreeMulticastUrl(), "--channels", "(", "--out", log},
      scratch.path() + "/record");
  EXPECT_EQ(record.Wait(30), 2);
  EXPECT_EQ(record.Stderr(),
            "tools/record: error: --channels '(' is not a regular expression (Mismatched '(' and "
            "')' in regular expression)\n");
  EXPECT_FALSE(fs::exists(log));
}

// tools/record refuses a log file that exists, and leaves it alone.
TEST(LcmToolsTest, RecordRefusesExistingFile) {
  const ScratchDir scratch("lcm-tools");
  const std::string log = scratch.path() + "/old.lcmlog";
  { std::ofstream(log) << "keep"; }
  Process record({kRecord, "--lcm-url", testing::FreeMulticastUrl(), "--out", log},
                 scratch.path() + "/record");
  EXPECT_EQ(record.Wait(30), 2);
  EXPECT_NE(record.Stderr().find(log + " exists"), std::string::npos) << record.Stderr();
  EXPECT_EQ(testing::ReadFile(log), "keep");
}

// tools/record on a bus it cannot record (not udpm://) says why in one line and leaves no log;
// stopped before anything arrived, it says so and leaves no log either (an empty file is not an
// LCM log).
TEST(LcmToolsTest, RecordLeavesNoEmptyLog) {
  const ScratchDir scratch("lcm-tools");
  const std::string bad_log = scratch.path() + "/bad.lcmlog";
  Process bad({kRecord, "--lcm-url", "bogus://x", "--out", bad_log}, scratch.path() + "/bad");
  EXPECT_EQ(bad.Wait(30), 2);
  EXPECT_EQ(bad.Stderr(), "tools/record: error: --lcm-url: not a udpm:// URL: bogus://x\n");
  EXPECT_FALSE(fs::exists(bad_log));

  const std::string quiet_log = scratch.path() + "/quiet.lcmlog";
  const std::string url = testing::FreeMulticastUrl();
  Process quiet({kRecord, "--lcm-url", url, "--out", quiet_log}, scratch.path() + "/quiet");
  ASSERT_TRUE(quiet.WaitForOutput("Ctrl-C stops", 30)) << quiet.Stderr();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  quiet.Signal(SIGINT);
  EXPECT_EQ(quiet.Wait(30), 1);
  EXPECT_NE(quiet.Stderr().find("tools/record: error: nothing arrived on "), std::string::npos)
      << quiet.Stderr();
  EXPECT_FALSE(fs::exists(quiet_log));
}

}  // namespace
}  // namespace stackgen
