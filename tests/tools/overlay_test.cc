// Runs the stackgen-overlay program as a process on COCO datasets written by CocoWriter and on
// damaged copies of them: it draws the masks of one image, and a bad file gets one line naming
// the file, the annotation and the field.

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "consumers/coco/coco_writer.h"
#include "tests/consumers/coco/coco_test_scenes.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::Process;
using testing::ScratchDir;

const std::string kProgram = std::string(STACKGEN_BIN_DIR) + "/stackgen-overlay";

// runs stackgen-overlay with `args` to the end; returns its exit code
int RunToEnd(const std::vector<std::string>& args, const std::string& log_prefix, std::string* out,
             std::string* err) {
  return testing::RunToEnd(kProgram, args, log_prefix, out, err, 60);
}

// a dataset of scenes A and B in `dir`
void WriteDataset(const std::string& dir) {
  CocoWriter writer(dir);
  ASSERT_TRUE(writer.Add(testing::SceneA()));
  ASSERT_TRUE(writer.Add(testing::SceneB()));
  writer.Finish();
}

// An intact dataset is drawn; damaged copies get one line naming the file, and for an
// annotation its id, its image and the field: broken JSON, an RLE string that is not one, a
// missing image file (OpenCV's own warning does not show).
TEST(OverlayTest, DamagedDatasetsAreOneLine) {
  const ScratchDir scratch("overlay");
  const std::string good = scratch.path() + "/good";
  WriteDataset(good);
  std::string out, err;
  ASSERT_EQ(
      RunToEnd({good, scratch.path() + "/good.png"}, scratch.path() + "/good-run", &out, &err), 0)
      << err;
  EXPECT_TRUE(fs::exists(scratch.path() + "/good.png"));
  const std::string text = testing::ReadFile(good + "/annotations.json");

  // broken JSON
  const std::string cut = scratch.path() + "/cut";
  fs::copy(good, cut, fs::copy_options::recursive);
  std::ofstream(cut + "/annotations.json") << text.substr(0, text.size() / 2);
  EXPECT_EQ(RunToEnd({cut, scratch.path() + "/cut.png"}, scratch.path() + "/cut-run", &out, &err),
            1);
  EXPECT_EQ(err.rfind("stackgen-overlay: error: " + cut + "/annotations.json: not valid JSON", 0),
            0u)
      << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;

  // an RLE string that is not one
  const std::string bad_rle = scratch.path() + "/rle";
  fs::copy(good, bad_rle, fs::copy_options::recursive);
  json dataset = json::parse(text);
  const int64_t image_id = dataset["images"][0]["id"];
  json* first = nullptr;
  for (json& annotation : dataset["annotations"]) {
    if (annotation["image_id"] == image_id && first == nullptr) first = &annotation;
  }
  ASSERT_NE(first, nullptr);
  (*first)["segmentation"]["counts"] = "zz!!";
  std::ofstream(bad_rle + "/annotations.json") << dataset.dump();
  EXPECT_EQ(
      RunToEnd({bad_rle, scratch.path() + "/rle.png"}, scratch.path() + "/rle-run", &out, &err), 1);
  EXPECT_EQ(err.rfind("stackgen-overlay: error: " + bad_rle + "/annotations.json: annotation " +
                          (*first)["id"].dump() + " (image " + std::to_string(image_id) +
                          "): segmentation.counts: ",
                      0),
            0u)
      << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;

  // the image file gone
  const std::string no_image = scratch.path() + "/no-image";
  fs::copy(good, no_image, fs::copy_options::recursive);
  const std::string file =
      no_image + "/images/" + dataset["images"][0]["file_name"].get<std::string>();
  fs::remove(file);
  EXPECT_EQ(
      RunToEnd({no_image, scratch.path() + "/ni.png"}, scratch.path() + "/ni-run", &out, &err), 1);
  EXPECT_EQ(err, "stackgen-overlay: error: " + no_image +
                     "/annotations.json: images[0]: its image " + file + " does not exist\n");
  EXPECT_FALSE(fs::exists(scratch.path() + "/ni.png"));
}

}  // namespace
}  // namespace stackgen
