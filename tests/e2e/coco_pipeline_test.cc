// Starts stackgen-coco and stackgen as separate processes on a free multicast port and checks
// the COCO dataset they make.

#include <sys/stat.h>

#include <map>
#include <set>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "gen/annotate/rle.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using nlohmann::json;
using testing::Process;

constexpr int kScenes = 3;

// runs the writer and the generator once; returns the parsed annotations.json.
json GenerateDataset(const std::string& dir, uint64_t seed) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string bin = STACKGEN_BIN_DIR;
  mkdir(dir.c_str(), 0755);
  Process coco({bin + "/stackgen-coco", "--out", dir + "/coco", "--count", std::to_string(kScenes),
                "--lcm-url", url},
               dir + "/coco");
  EXPECT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process generator(
      {bin + "/stackgen", "--config", testing::kLandedRule, "--count", std::to_string(kScenes),
       "--seed", std::to_string(seed), "--lcm-url", url, "--cache-dir", dir + "/cache"},
      dir + "/stackgen");
  EXPECT_EQ(generator.Wait(600), 0) << generator.Stderr();
  EXPECT_EQ(coco.Wait(60), 0) << coco.Stderr();
  EXPECT_NE(coco.Stdout().find("3 images"), std::string::npos) << coco.Stdout();
  const std::string text = testing::ReadFile(dir + "/coco/annotations.json");
  return json::parse(text);
}

// the dataset is complete and every label agrees with its pixels; the same seed gives the same
// annotations in a second run.
TEST(CocoPipelineTest, DatasetIsConsistentAndDeterministic) {
  const std::string dir = testing::MakeTempDir("stackgen-e2e");
  const json dataset = GenerateDataset(dir + "/a", 11);

  // every image exists with the camera's size.
  ASSERT_EQ(dataset["images"].size(), static_cast<size_t>(kScenes));
  std::map<int64_t, std::pair<int, int>> sizes;
  for (const json& image : dataset["images"]) {
    const cv::Mat pixels = cv::imread(
        dir + "/a/coco/images/" + image["file_name"].get<std::string>(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(pixels.empty()) << image["file_name"];
    EXPECT_EQ(pixels.cols, image["width"].get<int>());
    EXPECT_EQ(pixels.rows, image["height"].get<int>());
    EXPECT_EQ(pixels.cols, 640);
    EXPECT_EQ(pixels.rows, 480);
    sizes[image["id"].get<int64_t>()] = {pixels.rows, pixels.cols};
  }

  // every annotation's mask decodes to its area, lies in its box; masks of one image are apart.
  ASSERT_GT(dataset["annotations"].size(), 0u);
  std::map<int64_t, cv::Mat> covered;
  for (const json& annotation : dataset["annotations"]) {
    const int64_t image_id = annotation["image_id"].get<int64_t>();
    ASSERT_EQ(sizes.count(image_id), 1u);
    const auto [height, width] = sizes[image_id];
    const json& segmentation = annotation["segmentation"];
    ASSERT_EQ(segmentation["size"][0].get<int>(), height);
    ASSERT_EQ(segmentation["size"][1].get<int>(), width);
    const cv::Mat mask = DecodeRle(segmentation["counts"].get<std::string>(), height, width);
    const int area = cv::countNonZero(mask);
    EXPECT_EQ(area, annotation["area"].get<int>());
    EXPECT_GT(area, 0);
    const json& box = annotation["bbox"];
    const cv::Rect rect(box[0].get<int>(), box[1].get<int>(), box[2].get<int>(), box[3].get<int>());
    EXPECT_EQ(cv::countNonZero(mask(rect)), area) << "mask outside its bbox";
    // the default occlusion rule is DROP: no ignore regions (iscrowd 1)
    EXPECT_EQ(annotation["iscrowd"].get<int>(), 0);
    // the full (amodal) mask decodes to px_count_all pixels inside amodal_bbox = bbox_obj
    const json& amodal = annotation["amodal_segmentation"];
    ASSERT_TRUE(amodal.is_object()) << "no amodal_segmentation";
    ASSERT_EQ(amodal["size"], segmentation["size"]);
    const cv::Mat full = DecodeRle(amodal["counts"].get<std::string>(), height, width);
    const int full_area = cv::countNonZero(full);
    EXPECT_EQ(full_area, annotation["px_count_all"].get<int>());
    EXPECT_GE(full_area, area);
    const json& amodal_box = annotation["amodal_bbox"];
    EXPECT_EQ(amodal_box, annotation["bbox_obj"]);
    const cv::Rect full_rect(amodal_box[0].get<int>(), amodal_box[1].get<int>(),
                             amodal_box[2].get<int>(), amodal_box[3].get<int>());
    EXPECT_EQ(cv::countNonZero(full(full_rect)), full_area) << "full mask outside amodal_bbox";
    const double visib_fract = annotation["visib_fract"].get<double>();
    EXPECT_GT(visib_fract, 0.0);
    EXPECT_LE(visib_fract, 1.0);
    EXPECT_GE(visib_fract, 0.3) << "below the default visibility threshold";
    cv::Mat& image_cover = covered[image_id];
    if (image_cover.empty()) image_cover = cv::Mat::zeros(height, width, CV_8UC1);
    cv::Mat overlap;
    cv::bitwise_and(image_cover, mask, overlap);
    EXPECT_EQ(cv::countNonZero(overlap), 0) << "instance masks overlap";
    image_cover |= mask;
  }

  // a second run with the same seed gives identical annotations.
  const json again = GenerateDataset(dir + "/b", 11);
  EXPECT_EQ(dataset["annotations"], again["annotations"]);
  EXPECT_EQ(dataset["images"], again["images"]);
}

}  // namespace
}  // namespace stackgen
