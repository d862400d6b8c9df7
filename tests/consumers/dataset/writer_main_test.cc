// The program around every dataset writer (consumers/dataset/writer_main.h), run as
// stackgen-coco and stackgen-bop on the recorded fixture log: a writer never writes into a folder
// that is not its own dataset, and a run that stops before storing anything leaves nothing.

#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/datasets.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;

const std::string kLog = std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog";
// the programs and their journals
const std::vector<std::pair<std::string, std::string>> kWriters = {
    {"stackgen-coco", "annotations.journal"}, {"stackgen-bop", "bop.journal"}};

// runs `program` on the fixture log (recorded on an open bus) into `out`
int Write(const std::string& program, const std::string& out, std::vector<std::string> extra,
          const std::string& log_prefix, std::string* err) {
  std::vector<std::string> args = {"--out", out, "--lcm-url", "file://" + kLog + "?speed=0"};
  args.insert(args.end(), extra.begin(), extra.end());
  std::string out_text;
  return testing::RunToEnd(std::string(STACKGEN_BIN_DIR) + "/" + program, args, log_prefix,
                           &out_text, err, 120);
}

// A folder that holds anything but the writer's own dataset is refused in one line naming it
// and what it holds, with or without --resume, and left as it was: a BOP dataset whose journal
// is gone (stackgen-bop used to write over its images), a photo, the other writer's dataset.
TEST(WriterMainTest, AFolderNotItsOwnIsLeftAlone) {
  const testing::ScratchDir scratch("writer-main");
  const std::string logs = scratch.path() + "/logs";
  fs::create_directory(logs);
  std::string err;
  // a finished BOP dataset, its journal removed
  const std::string bop = scratch.path() + "/bop";
  ASSERT_EQ(Write("stackgen-bop", bop, {"--open-bus"}, logs + "/make", &err), 0) << err;
  fs::remove(bop + "/bop.journal");
  const auto before = testing::DatasetFiles(bop, "");
  // a folder with a photo in it
  const std::string photos = scratch.path() + "/photos";
  fs::create_directory(photos);
  std::ofstream(photos + "/IMG_0001.jpg") << "a photo";

  for (const auto& [program, journal] : kWriters) {
    for (const std::string& folder : {bop, photos}) {
      for (const bool resume : {false, true}) {
        SCOPED_TRACE(program + " " + folder + (resume ? " --resume" : ""));
        std::vector<std::string> extra = {"--open-bus"};
        if (resume) extra.push_back("--resume");
        EXPECT_EQ(Write(program, folder, extra, logs + "/run", &err), 1);
        EXPECT_EQ(err.rfind(program + ": error: " + folder + " is not empty (it holds ", 0), 0u)
            << err;
        EXPECT_NE(err.find("no " + journal), std::string::npos) << err;
        EXPECT_EQ(err.find('\n'), err.size() - 1) << err;
      }
    }
  }
  EXPECT_EQ(testing::DatasetFiles(bop, ""), before) << "the BOP dataset was changed";
  EXPECT_EQ(testing::ReadFile(photos + "/IMG_0001.jpg"), "a photo");
  EXPECT_EQ(std::distance(fs::directory_iterator(photos), fs::directory_iterator()), 1);
}

// A folder with the writer's journal is its dataset: continued with --resume, refused without.
TEST(WriterMainTest, ItsOwnDatasetNeedsResume) {
  const testing::ScratchDir scratch("writer-main");
  for (const auto& [program, journal] : kWriters) {
    SCOPED_TRACE(program);
    const std::string out = scratch.path() + "/" + program;
    std::string err;
    ASSERT_EQ(Write(program, out, {"--open-bus"}, out + "-a", &err), 0) << err;
    EXPECT_EQ(Write(program, out, {"--open-bus"}, out + "-b", &err), 1);
    EXPECT_NE(err.find(out + " holds a " + program + " dataset (" + journal +
                       "): continue it with --resume"),
              std::string::npos)
        << err;
    EXPECT_EQ(Write(program, out, {"--open-bus", "--resume"}, out + "-c", &err), 0) << err;
  }
}

// A log refused whole by the bus key (the fixture log is unsigned, read here with the suite's
// key) is one line saying what to do, exit 1, and no dataset folder left behind.
TEST(WriterMainTest, ARefusedLogLeavesNothing) {
  const testing::ScratchDir scratch("writer-main");
  for (const auto& [program, journal] : kWriters) {
    SCOPED_TRACE(program);
    const std::string out = scratch.path() + "/" + program;
    std::string err;
    EXPECT_EQ(Write(program, out, {}, out + "-run", &err), 1);
    EXPECT_EQ(err.rfind(program + ": error: the messages on STACKGEN_SCENE, STACKGEN_CONFIG of "
                                  "file://",
                        0),
              0u)
        << err;
    EXPECT_NE(err.find("are not signed"), std::string::npos) << err;
    EXPECT_EQ(err.find('\n'), err.size() - 1) << err;
    EXPECT_FALSE(fs::exists(out)) << out << " was left behind";
  }
}

}  // namespace
}  // namespace stackgen
