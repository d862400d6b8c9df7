// Makes 100 scenes of config/default.pbtxt (seed 0) with stackgen and stackgen-coco as separate
// processes on a free multicast port, and has stackgen-stats compare their piles with those the
// default made when piles were first proven at rest and faster rest was asked for (commit
// 8794ea7, the same config, seed and count: tests/fixtures/stats). Cheaper rest must not make
// another kind of pile; the heights are the one test that says it does (below).

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fstream>
#include <string>

#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::Process;

TEST(SamePilesTest, PosturesFacesAndPlacesAreThoseOf8794ea7) {
  const std::string dir = testing::MakeTempDir("stackgen-same-piles");
  const std::string bin = STACKGEN_BIN_DIR;
  const std::string url = testing::FreeMulticastUrl();
  Process coco({bin + "/stackgen-coco", "--out", dir + "/new", "--count", "100", "--lcm-url", url},
               dir + "/coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process generator({bin + "/stackgen", "--config",
                     std::string(STACKGEN_SOURCE_DIR) + "/config/default.pbtxt", "--count",
                     "100", "--seed", "0", "--lcm-url", url, "--cache-dir", dir + "/cache"},
                    dir + "/stackgen");
  ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stderr();

  // the fixture as a dataset folder of its own
  const std::string old = dir + "/8794ea7";
  mkdir(old.c_str(), 0755);
  const std::string fixture = testing::ReadFile(
      std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/stats/piles_8794ea7_default_seed0.json");
  ASSERT_FALSE(fixture.empty());
  std::ofstream(old + "/annotations.json") << fixture;

  Process stats({bin + "/stackgen-stats", old, dir + "/new", "--out", dir + "/plots"},
                dir + "/stats");
  ASSERT_EQ(stats.Wait(120), 0) << stats.Stderr();
  // The postures, resting faces and places in the bin are the same kind (each test's line ends
  // "same"). The heights are not asserted: today's parts lie lower, and the one landing rule
  // found that gives 8794ea7's heights breaks the rest proof (docs/results.md, "Piles at rest";
  // issue 41).
  const std::string out = "\n" + stats.Stdout();
  for (const std::string test : {"alpha", "beta", "gamma", "heading", "face", "radius"}) {
    const size_t line = out.find("\n" + test + ": ");
    ASSERT_NE(line, std::string::npos) << test << "\n" << out;
    const size_t end = out.find('\n', line + 1);
    EXPECT_EQ(out.substr(end - 5, 5), " same") << out.substr(line + 1, end - line - 1);
  }
  EXPECT_NE(out.find("\nheight: D="), std::string::npos) << out;
  // both datasets whole: the fixture's 818 parts, and 100 scenes made here
  EXPECT_NE(out.find("A: " + old + " (COCO): 818 instances of 100 images"), std::string::npos)
      << out;
  EXPECT_NE(out.find("B: " + dir + "/new (COCO): "), std::string::npos) << out;
  EXPECT_NE(out.find(" of 100 images", out.find("B: ")), std::string::npos) << out;
}

}  // namespace
}  // namespace stackgen
