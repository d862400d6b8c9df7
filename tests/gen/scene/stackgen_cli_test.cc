// The stackgen program refuses bad input (and a second generator with its id on the bus) with
// one clear line and a non-zero exit, and answers --help.

#include <algorithm>
#include <array>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::Process;

struct Outcome {
  int code;
  std::string out;
  std::string err;
};

Outcome RunStackgen(const std::vector<std::string>& args, const std::string& dir) {
  std::vector<std::string> argv = {std::string(STACKGEN_BIN_DIR) + "/stackgen"};
  argv.insert(argv.end(), args.begin(), args.end());
  Process process(argv, dir + "/run");
  const int code = process.Wait(120);
  return {code, process.Stdout(), process.Stderr()};
}

std::string WriteConfig(const std::string& dir, const std::string& text) {
  const std::string path = dir + "/bad.pbtxt";
  std::ofstream(path) << text;
  return path;
}

// stderr is exactly one line.
void ExpectOneLine(const std::string& err) {
  ASSERT_FALSE(err.empty());
  EXPECT_EQ(err.find('\n'), err.size() - 1) << err;
}

// --help lists every flag with its default.
TEST(StackgenCliTest, Help) {
  const Outcome outcome = RunStackgen({"--help"}, testing::MakeTempDir("stackgen-cli"));
  EXPECT_EQ(outcome.code, 0);
  for (const char* flag :
       {"--config", "--count", "--seed", "--generator-id", "--lcm-url", "--cache-dir", "default"}) {
    EXPECT_NE(outcome.out.find(flag), std::string::npos) << flag;
  }
}

// a negative count is a usage error naming the flag.
TEST(StackgenCliTest, NegativeCount) {
  const Outcome outcome = RunStackgen({"--count", "-3"}, testing::MakeTempDir("stackgen-cli"));
  EXPECT_EQ(outcome.code, 2);
  EXPECT_NE(outcome.err.find("--count"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// a missing mesh names the file.
TEST(StackgenCliTest, MissingMesh) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const std::string config = WriteConfig(dir, "part { mesh: \"no_such_part.stl\" }\n");
  const Outcome outcome =
      RunStackgen({"--config", config, "--count", "1", "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("no_such_part.stl"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// a tote mesh that does not enclose the configured inner box names the mesh and bin.mesh.
TEST(StackgenCliTest, ToteMeshTooSmall) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  std::ofstream(dir + "/tote.obj") << "v -10 -10 0\nv 10 -10 0\nv 0 10 0\nv 0 0 10\n"
                                      "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n";
  const std::string config =
      WriteConfig(dir, "part { mesh: \"" + std::string(STACKGEN_SOURCE_DIR) +
                           "/config/models/corner_connector.obj\" }\nbin { mesh: \"tote.obj\" }\n");
  const Outcome outcome =
      RunStackgen({"--config", config, "--count", "1", "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("tote.obj: bin.mesh"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// an empty mesh file names the file.
TEST(StackgenCliTest, EmptyMesh) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  std::ofstream(dir + "/empty.obj") << "# nothing\n";
  const std::string config = WriteConfig(dir, "part { mesh: \"empty.obj\" }\n");
  const Outcome outcome =
      RunStackgen({"--config", config, "--count", "1", "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("empty.obj"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// an unknown config field names the file and line.
TEST(StackgenCliTest, UnknownField) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const std::string config = WriteConfig(dir, "bin {\n  inner_length_mm: 300\n  depth: 3\n}\n");
  const Outcome outcome = RunStackgen({"--config", config, "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("bad.pbtxt:3:"), std::string::npos) << outcome.err;
  EXPECT_NE(outcome.err.find("depth"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// a bin too small for the parts is refused, naming the config file.
TEST(StackgenCliTest, BinTooSmall) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const std::string config = WriteConfig(dir, "part { mesh: \"" STACKGEN_SOURCE_DIR
                                              "/config/models/corner_connector.obj\" }\n"
                                              "bin { inner_length_mm: 30 inner_width_mm: 30 }\n");
  const Outcome outcome =
      RunStackgen({"--config", config, "--count", "1", "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("bad.pbtxt"), std::string::npos) << outcome.err;
  EXPECT_NE(outcome.err.find("bin"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// an ASCII STL of a box with sides lx, ly, lz (in the file's units) at `path`.
void WriteBoxStl(const std::string& path, double lx, double ly, double lz) {
  const int quads[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                           {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  std::ofstream stl(path);
  stl << "solid box\n";
  for (const auto& quad : quads) {
    const std::array<std::array<int, 3>, 2> triangles = {
        {{quad[0], quad[1], quad[2]}, {quad[0], quad[2], quad[3]}}};
    for (const std::array<int, 3>& triangle : triangles) {
      stl << " facet normal 0 0 0\n  outer loop\n";
      for (int k = 0; k < 3; ++k) {
        const int v = triangle[k];
        stl << "   vertex " << (v & 4 ? lx : 0) << " " << (v & 2 ? ly : 0) << " "
            << (v & 1 ? lz : 0) << "\n";
      }
      stl << "  endloop\n endfacet\n";
    }
  }
  stl << "endsolid box\n";
}

// a part exported in metres (an 80 x 40 x 10 mm box as 0.08 x 0.04 x 0.01) is refused with its
// size and the hint; with scale_to_mm: 1000 it is checked and its size printed.
TEST(StackgenCliTest, PartInMetresIsRefusedWithTheHint) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  WriteBoxStl(dir + "/box.stl", 0.08, 0.04, 0.01);
  const std::string config = WriteConfig(dir, "part { mesh: \"box.stl\" count: 3 }\n");
  const Outcome outcome = RunStackgen(
      {"--config", config, "--check", "--lcm-url", "memq://", "--cache-dir", dir + "/cache"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("box.stl) is 0.08 x 0.04 x 0.01 mm, 0.14 px across"),
            std::string::npos)
      << outcome.err;
  EXPECT_NE(outcome.err.find("a mesh in metres needs scale_to_mm: 1000"), std::string::npos)
      << outcome.err;
  ExpectOneLine(outcome.err);

  std::ofstream(config) << "part { mesh: \"box.stl\" count: 3 scale_to_mm: 1000 }\n";
  const Outcome scaled = RunStackgen(
      {"--config", config, "--check", "--lcm-url", "memq://", "--cache-dir", dir + "/cache"}, dir);
  EXPECT_EQ(scaled.code, 0) << scaled.err;
  EXPECT_NE(scaled.out.find("80.0 x 40.0 x 10.0 mm, 142 px across at 450 mm"), std::string::npos)
      << scaled.out;
}

// a missing config file names it.
TEST(StackgenCliTest, MissingConfig) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const Outcome outcome = RunStackgen({"--config", dir + "/nope.pbtxt"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("nope.pbtxt"), std::string::npos) << outcome.err;
  ExpectOneLine(outcome.err);
}

// a part mesh cut off at 90 % of its file (a damaged download) is refused, naming the file, as
// not a closed solid (it passed before, with a wrong mass and collision shape).
TEST(StackgenCliTest, TruncatedMeshNamesTheFile) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const std::string whole =
      testing::ReadFile(std::string(STACKGEN_SOURCE_DIR) + "/config/models/corner_connector.obj");
  const std::string cut = dir + "/cut.obj";
  std::ofstream(cut) << whole.substr(0, whole.size() * 9 / 10);
  std::ofstream(dir + "/corner_connector.mtl") << testing::ReadFile(
      std::string(STACKGEN_SOURCE_DIR) + "/config/models/corner_connector.mtl");
  const std::string config = WriteConfig(dir, "part { mesh: \"cut.obj\" count: 3 }\n");
  const Outcome outcome = RunStackgen(
      {"--config", config, "--check", "--lcm-url", "memq://", "--cache-dir", dir + "/cache"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_NE(outcome.err.find("mesh file '" + cut + "' is not a closed solid"), std::string::npos)
      << outcome.err;
  ExpectOneLine(outcome.err);
}

// a folder given as --config is refused as a folder (it read as an empty config before, and the
// error named the default mesh).
TEST(StackgenCliTest, FolderAsConfig) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const Outcome outcome = RunStackgen({"--config", dir, "--lcm-url", "memq://"}, dir);
  EXPECT_EQ(outcome.code, 1);
  EXPECT_EQ(outcome.err, "stackgen: error: " + dir +
                             ": is a folder, not a config file (protobuf text, e.g. "
                             "config/default.pbtxt)\n");
}

// --check builds everything a run needs and exits 0 without publishing; a bad bus fails it.
TEST(StackgenCliTest, CheckPublishesNothing) {
  const std::string dir = testing::MakeTempDir("stackgen-cli");
  const std::string url = testing::FreeMulticastUrl();
  Bus bus(url);
  int heard = 0;
  bus.Subscribe<status>(kStatusChannel, [&](const status&) { ++heard; });
  const Outcome ok = RunStackgen({"--check", "--lcm-url", url}, dir);
  EXPECT_EQ(ok.code, 0) << ok.err;
  EXPECT_NE(ok.out.find("--check: the config, the bus and the renderer are usable"),
            std::string::npos)
      << ok.out;
  bus.HandleFor(300);
  EXPECT_EQ(heard, 0);
  const Outcome bad = RunStackgen({"--check", "--lcm-url", "bogus://x"}, dir);
  EXPECT_EQ(bad.code, 1);
  EXPECT_EQ(bad.err,
            "stackgen: error: cannot open the LCM bus at bogus://x: LCM provider \"bogus\" not "
            "found\n");
}

// a run whose scenes no reliable consumer took ends with an error (exit 1) after its summary,
// one line naming the bus; --no-consumer-ok accepts listeners alone.
TEST(StackgenCliTest, NoReliableConsumerIsAnError) {
  const testing::ScratchDir scratch("stackgen-cli");
  const std::string dir = scratch.path();
  const std::vector<std::string> args = {"--count", "1",           "--lcm-url",
                                         "memq://", "--cache-dir", dir + "/cache"};
  const Outcome alone = RunStackgen(args, dir);
  EXPECT_EQ(alone.code, 1);
  ExpectOneLine(alone.err);
  EXPECT_NE(alone.err.find("stackgen: error: published 1 scene on memq:// and no reliable "
                           "consumer"),
            std::string::npos)
      << alone.err;
  EXPECT_NE(alone.out.find("stackgen: 1 scenes in"), std::string::npos) << alone.out;
  std::vector<std::string> ok_args = args;
  ok_args.push_back("--no-consumer-ok");
  const Outcome ok = RunStackgen(ok_args, dir);
  EXPECT_EQ(ok.code, 0) << ok.err;
}

// a generator that runs on with no reliable consumer says so while it runs (within 10 s), not
// only at its end, which --count 0 never reaches; it goes on, and stops at a signal with 0.
TEST(StackgenCliTest, AGeneratorWithNoConsumerWarnsWhileItRuns) {
  const testing::ScratchDir scratch("stackgen-cli");
  const std::string dir = scratch.path();
  Process generator({std::string(STACKGEN_BIN_DIR) + "/stackgen", "--config",
                     std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.pbtxt",
                     "--lcm-url", "memq://", "--cache-dir", dir + "/cache"},
                    dir + "/alone");
  // (the config and the shaders take a few seconds before the run starts)
  ASSERT_TRUE(generator.WaitForError("stackgen: warning: no reliable consumer", 60))
      << generator.Stderr();
  EXPECT_FALSE(generator.Exited());
  const std::string said = generator.Stderr();
  EXPECT_NE(said.find("reach listeners only; start the writer on memq://"), std::string::npos)
      << said;
  generator.Signal(SIGINT);
  EXPECT_EQ(generator.Wait(60), 0) << generator.Stderr();
}

// a second generator with the same --generator-id on the same bus refuses to run, naming the id
// and the first one, while the first (it has published more) goes on with a warning.
TEST(StackgenCliTest, SameGeneratorIdRefused) {
  const testing::ScratchDir scratch("stackgen-cli");
  const std::string dir = scratch.path();
  const std::string url = testing::FreeMulticastUrl();
  const std::string bin = std::string(STACKGEN_BIN_DIR) + "/stackgen";
  Bus bus(url);
  int64_t first_scenes = 0;
  bus.Subscribe<stackgen::status>(kStatusChannel, [&](const stackgen::status& message) {
    if (message.process == "stackgen") first_scenes = std::max(first_scenes, message.scenes);
  });
  Process first({bin, "--generator-id", "3", "--lcm-url", url, "--cache-dir", dir + "/cache"},
                dir + "/first");
  for (int i = 0; i < 600 && first_scenes < 1; ++i) bus.HandleFor(100);
  ASSERT_GE(first_scenes, 1) << first.Stderr();

  Process second({bin, "--generator-id", "3", "--lcm-url", url, "--cache-dir", dir + "/cache"},
                 dir + "/second");
  EXPECT_EQ(second.Wait(120), 1);
  const std::string err = second.Stderr();
  ExpectOneLine(err);
  EXPECT_NE(err.find("another generator with --generator-id 3"), std::string::npos) << err;
  EXPECT_NE(err.find("stackgen/3@"), std::string::npos) << err;

  first.Signal(SIGINT);
  EXPECT_EQ(first.Wait(60), 0) << first.Stderr();
  EXPECT_NE(first.Stderr().find("warning: another generator with --generator-id 3"),
            std::string::npos)
      << first.Stderr();
}

}  // namespace
}  // namespace stackgen
