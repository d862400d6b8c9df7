// Runs the stackgen-view program as a process: contact sheets of a COCO dataset written by
// CocoWriter, of the BOP dataset stackgen-bop writes from the fixture log, and of scenes sent over
// real UDP multicast on this host, its errors, and scenes it must skip.

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stackgen/header.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "consumers/coco/coco_writer.h"
#include "tests/consumers/coco/coco_test_scenes.h"
#include "tests/support/live_bus.h"
#include "tests/support/process.h"
#include "tests/support/bop_fixture.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using testing::Process;
using testing::ScratchDir;

const std::string kProgram = std::string(STACKGEN_BIN_DIR) + "/stackgen-view";

// the layout and colours stackgen-view --help documents (colours in OpenCV's BGR order)
constexpr int kLegendHeight = 44;
constexpr int kCaptionHeight = 20;
constexpr int kGap = 4;
const cv::Vec3b kAnnotated(0, 230, 0);    // #00E600
const cv::Vec3b kIgnored(0, 150, 255);    // #FF9600
const cv::Vec3b kDropped(160, 160, 160);  // #A0A0A0

// the size of a sheet of `rows` x `columns` tiles of `tile_width` x `tile_height`
cv::Size SheetSize(int columns, int rows, int tile_width, int tile_height) {
  return cv::Size(kGap + columns * (tile_width + kGap),
                  kLegendHeight + kGap + rows * (tile_height + kCaptionHeight + kGap));
}

// the tile in column `column`, row `row` of a sheet
cv::Rect TileRect(int column, int row, int tile_width, int tile_height) {
  return cv::Rect(kGap + column * (tile_width + kGap),
                  kLegendHeight + kGap + row * (tile_height + kCaptionHeight + kGap), tile_width,
                  tile_height);
}

// pixels of exactly `colour` in `region` of `sheet`
int CountColour(const cv::Mat& sheet, const cv::Rect& region, const cv::Vec3b& colour) {
  int count = 0;
  const cv::Mat part = sheet(region);
  for (int y = 0; y < part.rows; ++y) {
    for (int x = 0; x < part.cols; ++x) count += part.at<cv::Vec3b>(y, x) == colour;
  }
  return count;
}

// runs stackgen-view with `args` to the end; returns its exit code
int RunToEnd(const std::vector<std::string>& args, const std::string& log_prefix, std::string* out,
             std::string* err) {
  return testing::RunToEnd(kProgram, args, log_prefix, out, err, 60);
}

// publishes `message` on the scene channel and gives the receiver a moment
template <typename Message>
void Send(Bus& bus, const Message& message) {
  bus.Publish(kSceneChannel, message);
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

// --help documents every flag, its default, the colours and the small-object rule, and exits 0.
TEST(ViewTest, HelpListsEveryFlag) {
  const ScratchDir scratch("view");
  std::string out, err;
  EXPECT_EQ(RunToEnd({"--help"}, scratch.path() + "/help", &out, &err), 0);
  for (const char* text : {"--coco",
                           "--lcm-url",
                           "--out",
                           "--count",
                           "--columns",
                           "--tile-width",
                           "--timeout",
                           "--help",
                           "default 12",
                           "default 4",
                           "default 400",
                           "default 60",
                           "#00E600",
                           "#FF9600",
                           "#A0A0A0",
                           "1.5%",
                           "iscrowd 1",
                           "STACKGEN_LCM_URL",
                           "--bop DIR",
                           "--split NAME",
                           "default: train_pbr",
                           "mask_visib/IM_GT.png",
                           "visib_fract",
                           "at least 0.3",
                           "SCENE_ID/IM_ID"}) {
    EXPECT_NE(out.find(text), std::string::npos) << text << " missing from\n" << out;
  }
}

// A COCO dataset of 4 scenes, one with an annotated and an ignored (iscrowd 1) instance: the
// sheet has the documented size, annotated outlines green and the ignore region orange, only
// where they are.
TEST(ViewTest, DrawsCocoDataset) {
  const ScratchDir scratch("view");
  const std::string dataset = scratch.path() + "/coco";
  {
    CocoWriter writer(dataset);
    // image ids: A 1, B 2, C 100000001, D 200000001
    for (const stackgen::scene& scene :
         {testing::SceneD(), testing::SceneA(), testing::SceneC(), testing::SceneB()}) {
      ASSERT_TRUE(writer.Add(scene));
    }
    writer.Finish();
    ASSERT_EQ(writer.num_crowd(), 1);
  }
  const std::string sheet_path = scratch.path() + "/sheet.png";
  std::string out, err;
  ASSERT_EQ(RunToEnd({"--coco", dataset, "--out", sheet_path, "--count", "4", "--columns", "3",
                      "--tile-width", "200"},
                     scratch.path() + "/run", &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("4 scenes in 3 columns x 2 rows"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(sheet_path + ".tmp"));

  // 8 x 6 images at 200 px wide: tiles of 200 x 150, 3 columns, 2 rows
  const cv::Mat sheet = cv::imread(sheet_path, cv::IMREAD_COLOR);
  ASSERT_FALSE(sheet.empty());
  EXPECT_EQ(sheet.size(), SheetSize(3, 2, 200, 150));
  // tiles in image id order: A, B, C in the first row, D alone in the second
  const cv::Rect tile_a = TileRect(0, 0, 200, 150);
  const cv::Rect tile_d = TileRect(0, 1, 200, 150);
  EXPECT_GT(CountColour(sheet, tile_a, kAnnotated), 100);
  EXPECT_EQ(CountColour(sheet, tile_a, kIgnored), 0);
  EXPECT_GT(CountColour(sheet, tile_d, kAnnotated), 100);
  EXPECT_GT(CountColour(sheet, tile_d, kIgnored), 100);
  // the ignore region of D is the 50 x 50 px square at (125, 75) of its tile: orange there only
  const cv::Rect ignored_square(tile_d.x + 125 - 2, tile_d.y + 75 - 2, 54, 54);
  EXPECT_EQ(CountColour(sheet, ignored_square, kIgnored), CountColour(sheet, tile_d, kIgnored));
  // a COCO file holds no dropped instances
  for (int column = 0; column < 3; ++column) {
    EXPECT_EQ(CountColour(sheet, TileRect(column, 0, 200, 150), kDropped), 0) << column;
  }
  // --count takes the first images by id
  ASSERT_EQ(RunToEnd({"--coco", dataset, "--out", scratch.path() + "/two.png", "--count", "2"},
                     scratch.path() + "/run2", &out, &err),
            0)
      << err;
  EXPECT_EQ(cv::imread(scratch.path() + "/two.png").size(), SheetSize(2, 1, 400, 300));
}

// The BOP dataset of the fixture log (4 images of chunk 2000000): --count images in image id
// order, each ground truth outlined green when at least 30 % visible and orange when less, so a
// tile has orange exactly when its image has such a ground truth; the split is found (train_pbr,
// else the only one) or named with --split.
TEST(ViewTest, DrawsBopDataset) {
  const ScratchDir scratch("view");
  const std::string dataset = scratch.path() + "/bop";
  std::string output;
  ASSERT_EQ(testing::MakeFixtureBop(dataset, scratch.path() + "/bop", &output), 0) << output;
  // per image id, whether it has a ground truth with visible pixels less than 30 % visible
  std::vector<bool> has_orange;
  const nlohmann::json info = nlohmann::json::parse(
      testing::ReadFile(testing::FixtureChunk(dataset) + "/scene_gt_info.json"));
  for (int im_id = 0; im_id < 4; ++im_id) {
    bool orange = false;
    for (const nlohmann::json& truth : info.at(std::to_string(im_id))) {
      orange |= truth["px_count_visib"] > 0 && truth["visib_fract"] < 0.3;
    }
    has_orange.push_back(orange);
  }
  ASSERT_NE(std::count(has_orange.begin(), has_orange.end(), true), 0);
  ASSERT_NE(std::count(has_orange.begin(), has_orange.end(), false), 0);

  const std::string sheet_path = scratch.path() + "/sheet.png";
  std::string out, err;
  ASSERT_EQ(RunToEnd({"--bop", dataset, "--out", sheet_path, "--count", "4", "--columns", "3",
                      "--tile-width", "160"},
                     scratch.path() + "/run", &out, &err),
            0)
      << err;
  EXPECT_NE(out.find(dataset + "/train_pbr: 4 images of 1 scene folders"), std::string::npos)
      << out;
  EXPECT_NE(out.find("4 scenes in 3 columns x 2 rows"), std::string::npos) << out;
  // 160 x 120 images at 160 px wide: tiles of 160 x 120
  const cv::Mat sheet = cv::imread(sheet_path, cv::IMREAD_COLOR);
  ASSERT_FALSE(sheet.empty());
  EXPECT_EQ(sheet.size(), SheetSize(3, 2, 160, 120));
  for (int im_id = 0; im_id < 4; ++im_id) {
    const cv::Rect tile = TileRect(im_id % 3, im_id / 3, 160, 120);
    EXPECT_GT(CountColour(sheet, tile, kAnnotated), 100) << im_id;
    EXPECT_EQ(CountColour(sheet, tile, kIgnored) > 0, has_orange[im_id]) << im_id;
    // no outline in the dropped colour (tens of pixels; a rendered pixel may have it by chance)
    EXPECT_LT(CountColour(sheet, tile, kDropped), 10) << im_id;
  }

  // another split name: found when it is the only one, else named with --split
  fs::rename(dataset + "/train_pbr", dataset + "/val");
  ASSERT_EQ(RunToEnd({"--bop", dataset, "--out", scratch.path() + "/val.png", "--count", "2"},
                     scratch.path() + "/val", &out, &err),
            0)
      << err;
  EXPECT_EQ(cv::imread(scratch.path() + "/val.png").size(), SheetSize(2, 1, 400, 300));
  fs::copy(dataset + "/val", dataset + "/test", fs::copy_options::recursive);
  EXPECT_EQ(RunToEnd({"--bop", dataset, "--out", scratch.path() + "/two.png"},
                     scratch.path() + "/two", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: " + dataset +
                     " holds several BOP splits (test, val) and no train_pbr: name one with "
                     "--split\n");
  ASSERT_EQ(RunToEnd({"--bop", dataset, "--split", "test", "--out", scratch.path() + "/test.png",
                      "--count", "1"},
                     scratch.path() + "/test", &out, &err),
            0)
      << err;
  EXPECT_NE(out.find(dataset + "/test: 1 images of 1 scene folders"), std::string::npos) << out;

  // a mask file that is gone is named
  const std::string mask = dataset + "/test/2000000/mask_visib/000000_000002.png";
  fs::remove(mask);
  EXPECT_EQ(RunToEnd({"--bop", dataset, "--split", "test", "--out", scratch.path() + "/m.png"},
                     scratch.path() + "/mask", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: " + mask + " is missing (" + dataset +
                     "/test/2000000/scene_gt.json has image 0, gt 2)\n");
  EXPECT_FALSE(fs::exists(scratch.path() + "/m.png"));
}

// On the bus: --count distinct scenes are drawn (a repeat is skipped), a dropped instance is
// outlined gray, and the program exits by itself.
TEST(ViewTest, DrawsScenesFromTheBus) {
  const ScratchDir scratch("view");
  const std::string url = testing::FreeMulticastUrl();
  const std::string sheet_path = scratch.path() + "/sheet.png";
  Process view({kProgram, "--lcm-url", url, "--out", sheet_path, "--count", "3", "--columns", "2",
                "--tile-width", "80", "--timeout", "30"},
               scratch.path() + "/run");
  ASSERT_TRUE(view.WaitForOutput("listening on " + url + " channel STACKGEN_SCENE", 30))
      << view.Stderr();
  Bus bus(url);
  ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-view never answered";
  Send(bus, testing::SceneA());
  Send(bus, testing::SceneA());
  Send(bus, testing::SceneD());
  Send(bus, testing::SceneC());  // gray
  ASSERT_EQ(view.Wait(30), 0) << view.Stderr();
  EXPECT_NE(view.Stdout().find("3 scenes in 2 columns x 2 rows"), std::string::npos)
      << view.Stdout();
  const cv::Mat sheet = cv::imread(sheet_path, cv::IMREAD_COLOR);
  ASSERT_FALSE(sheet.empty());
  EXPECT_EQ(sheet.size(), SheetSize(2, 2, 80, 60));
  // A: instance 2 is visible but not annotated (gray); D: annotated and ignored
  EXPECT_GT(CountColour(sheet, TileRect(0, 0, 80, 60), kDropped), 0);
  EXPECT_GT(CountColour(sheet, TileRect(0, 0, 80, 60), kAnnotated), 0);
  EXPECT_GT(CountColour(sheet, TileRect(1, 0, 80, 60), kIgnored), 0);
  EXPECT_GT(CountColour(sheet, TileRect(0, 1, 80, 60), kAnnotated), 0);
  EXPECT_NE(view.Stderr().find("1 repeated"), std::string::npos) << view.Stderr();
}

// A message that is not a scene and scenes that disagree with themselves are skipped with a
// warning naming the field; the program goes on and draws the good ones, and its last status on
// STACKGEN_STATUS counts them.
TEST(ViewTest, SkipsCorruptScenes) {
  const ScratchDir scratch("view");
  const std::string url = testing::FreeMulticastUrl();
  const std::string sheet_path = scratch.path() + "/sheet.png";
  Process view({kProgram, "--lcm-url", url, "--out", sheet_path, "--count", "2", "--timeout", "30"},
               scratch.path() + "/run");
  ASSERT_TRUE(view.WaitForOutput("listening", 30)) << view.Stderr();
  Bus bus(url);
  ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-view never answered";
  std::vector<stackgen::status> statuses;
  bus.Subscribe<stackgen::status>(kStatusChannel,
                                  [&](const stackgen::status& m) { statuses.push_back(m); });
  stackgen::scene bad_mask = testing::SceneA();
  bad_mask.instances[0].mask_visib_rle = "1p";
  stackgen::scene short_image = testing::SceneD();
  short_image.color.data.resize(10);
  short_image.color.size = 10;
  Send(bus, stackgen::header{});
  Send(bus, bad_mask);
  Send(bus, short_image);
  Send(bus, testing::SceneA());  // the good copy of the scene skipped above
  Send(bus, testing::SceneB());
  ASSERT_EQ(view.Wait(30), 0) << view.Stderr();
  const std::string err = view.Stderr();
  EXPECT_NE(err.find("skipped scene 0/0: instances[0].mask_visib_rle"), std::string::npos) << err;
  // an image shorter than its size says is refused while decoding, before any allocation
  EXPECT_NE(err.find("color.size 10 != width*height*3"), std::string::npos) << err;
  EXPECT_NE(err.find("2 undecodable messages, 1 invalid scenes"), std::string::npos) << err;
  EXPECT_EQ(cv::imread(sheet_path).size(), SheetSize(2, 1, 400, 300));
  for (int i = 0; i < 50 && (statuses.empty() || statuses.back().scenes < 2); ++i) {
    bus.HandleFor(100);
  }
  ASSERT_FALSE(statuses.empty());
  const stackgen::status& last = statuses.back();
  EXPECT_EQ(last.process, "stackgen-view");
  EXPECT_EQ(last.scenes, 2);
  EXPECT_EQ(last.received, 3);
  EXPECT_EQ(last.bad_messages, 3);
}

// When fewer scenes than --count arrive before --timeout the sheet shows those; none is an error
// naming the URL, and no sheet is written.
TEST(ViewTest, TimeoutWritesWhatArrived) {
  const ScratchDir scratch("view");
  const std::string url = testing::FreeMulticastUrl();
  {
    Process view({kProgram, "--lcm-url", url, "--out", scratch.path() + "/one.png", "--count", "3",
                  "--timeout", "2"},
                 scratch.path() + "/one");
    ASSERT_TRUE(view.WaitForOutput("listening", 30)) << view.Stderr();
    Bus bus(url);
    ASSERT_TRUE(testing::WaitForLivePeer(bus, 10)) << "stackgen-view never answered";
    Send(bus, testing::SceneB());
    ASSERT_EQ(view.Wait(30), 0) << view.Stderr();
    EXPECT_NE(view.Stderr().find("only 1 of 3 scenes arrived before the timeout"),
              std::string::npos)
        << view.Stderr();
    EXPECT_EQ(cv::imread(scratch.path() + "/one.png").size(), SheetSize(1, 1, 400, 300));
  }
  std::string out, err;
  EXPECT_EQ(RunToEnd({"--lcm-url", url, "--out", scratch.path() + "/none.png", "--timeout", "1"},
                     scratch.path() + "/none", &out, &err),
            1);
  EXPECT_EQ(err.rfind("stackgen-view: error: --lcm-url " + url + ": no valid scene", 0), 0u) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_FALSE(fs::exists(scratch.path() + "/none.png"));
}

// A missing dataset folder is one error line naming it and exit 1; bad command lines exit 2.
TEST(ViewTest, BadInputIsOneLine) {
  const ScratchDir scratch("view");
  const std::string missing = scratch.path() + "/no-such-dataset";
  std::string out, err;
  EXPECT_EQ(RunToEnd({"--coco", missing, "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/missing", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: --coco " + missing + ": no such folder\n");
  EXPECT_FALSE(fs::exists(scratch.path() + "/s.png"));

  // an image file that is gone is named where stackgen-coco writes it (images/), not elsewhere
  const std::string dataset = scratch.path() + "/coco";
  {
    CocoWriter writer(dataset);
    ASSERT_TRUE(writer.Add(testing::SceneA()));
    writer.Finish();
  }
  fs::remove(dataset + "/images/0_000000.png");
  EXPECT_EQ(RunToEnd({"--coco", dataset, "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/no-image", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: " + dataset + "/annotations.json: image 1: its image " +
                     dataset + "/images/0_000000.png does not exist (nor " + dataset +
                     "/0_000000.png)\n");

  // a folder without annotations.json names the file
  fs::create_directory(scratch.path() + "/empty");
  EXPECT_EQ(RunToEnd({"--coco", scratch.path() + "/empty", "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/empty-run", &out, &err),
            1);
  EXPECT_NE(err.find(scratch.path() + "/empty/annotations.json"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;

  // --bop: a missing folder, a folder without a split
  EXPECT_EQ(RunToEnd({"--bop", missing, "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/bop-missing", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: --bop " + missing + ": no such folder\n");
  EXPECT_EQ(RunToEnd({"--bop", scratch.path() + "/empty", "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/bop-empty", &out, &err),
            1);
  EXPECT_EQ(err, "stackgen-view: error: --bop " + scratch.path() +
                     "/empty: no BOP split folder in it (SPLIT/SCENE_ID/scene_gt.json)\n");

  // a log whose scenes the bus key refuses (the fixture log is unsigned): one line saying so,
  // not a warning and an error; with --open-bus it is drawn
  const std::string log_url = "file://" + testing::kFixtureLog + "?speed=0";
  EXPECT_EQ(RunToEnd({"--lcm-url", log_url, "--out", scratch.path() + "/s.png"},
                     scratch.path() + "/unsigned", &out, &err),
            1);
  EXPECT_EQ(
      err.rfind(
          "stackgen-view: error: the messages on STACKGEN_SCENE, STACKGEN_CONFIG of " + log_url, 0),
      0u)
      << err;
  EXPECT_NE(err.find("are not signed"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_FALSE(fs::exists(scratch.path() + "/s.png"));
  EXPECT_EQ(RunToEnd({"--lcm-url", log_url, "--out", scratch.path() + "/s.png", "--open-bus",
                      "--count", "4"},
                     scratch.path() + "/open", &out, &err),
            0)
      << err;

  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--coco", scratch.path(), "--out", "s.png", "--count", "0"},
        {"--bop", scratch.path(), "--coco", scratch.path(), "--out", "s.png"},
        {"--bop", scratch.path(), "--lcm-url", "default", "--out", "s.png"},
        {"--bop", scratch.path(), "--out", "s.png", "--timeout", "5"},
        {"--coco", scratch.path(), "--out", "s.png", "--split", "train_pbr"},
        {"--bop", "", "--out", "s.png"},
        {"--coco", scratch.path(), "--out", "s.png", "--columns", "x"},
        {"--coco", scratch.path(), "--out", "s.png", "--tile-width", "8"},
        {"--coco", scratch.path(), "--out", "s.png", "--columns", "100", "--tile-width", "4096"},
        {"--coco", scratch.path(), "--out", "s.jpg"},
        {"--coco", scratch.path(), "--out", "s.png", "--timeout", "5"},
        {"--coco", scratch.path(), "--lcm-url", "default", "--out", "s.png"},
        {"--out", "s.png"},
        {"--coco", scratch.path()},
        {"--coco", scratch.path(), "--out", "s.png", "--bogus"},
        {"--lcm-url", "default", "--out", "s.png", "--open-bus", "--bus-key-file", "k"}}) {
    EXPECT_EQ(RunToEnd(args, scratch.path() + "/bad", &out, &err), 2) << args.back();
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_EQ(err.rfind("stackgen-view: error: ", 0), 0u) << err;
  }
}

}  // namespace
}  // namespace stackgen
