#include "consumers/feed/scene_data.h"

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stackgen/scene.hpp>

#include "bus/log.h"
#include "gen/annotate/rle.h"

namespace stackgen::feed {
namespace {

const std::string kLog = std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog";

// the scenes of the fixture log
std::vector<scene> FixtureScenes() {
  std::vector<scene> scenes;
  ReadLog(kLog, [&](const LogEvent& event) {
    if (event.channel == "STACKGEN_SCENE") scenes.push_back(DecodeLogEvent<scene>(event));
  });
  return scenes;
}

// the feed's decoder gives back, pixel for pixel, any mask the generator's encoder wrote
// (random blobs, empty, full, one pixel, masks whose runs wrap from column to column)
TEST(SceneDataTest, RleDecodesWhatTheGeneratorEncodes) {
  std::mt19937 engine(7);
  for (int trial = 0; trial < 60; ++trial) {
    const int height = 1 + static_cast<int>(engine() % 90);
    const int width = 1 + static_cast<int>(engine() % 120);
    cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
    const int kind = trial % 4;
    if (kind == 1) mask.setTo(1);
    if (kind == 2) mask.at<uint8_t>(static_cast<int>(engine() % height), 0) = 1;
    if (kind == 3) {
      for (int blob = 0; blob < 4; ++blob) {
        cv::circle(mask, {static_cast<int>(engine() % width), static_cast<int>(engine() % height)},
                   static_cast<int>(engine() % 20), 1, cv::FILLED);
      }
    }
    const std::string counts = EncodeRle(mask);
    std::vector<uint8_t> decoded(static_cast<size_t>(height) * width, 0);
    const int64_t set = DecodeRleInto(counts, height, width, decoded.data());
    EXPECT_EQ(set, cv::countNonZero(mask));
    EXPECT_EQ(cv::countNonZero(cv::Mat(height, width, CV_8UC1, decoded.data()) != mask), 0)
        << "trial " << trial << " " << height << "x" << width;
  }
}

// strings that are no COCO RLE of the image are refused, never decoded past the buffer
TEST(SceneDataTest, RleRefusesMalformedStrings) {
  std::vector<uint8_t> out(12, 0);
  for (const std::string& bad : {std::string("0~"), std::string("0"), std::string("="),
                                 EncodeRle(cv::Mat::ones(4, 4, CV_8UC1))}) {
    EXPECT_THROW(DecodeRleInto(bad, 3, 4, out.data()), std::runtime_error) << bad;
  }
}

// the images decode to what OpenCV reads from the PNG bytes, colour in R, G, B order; a RAW image
// is used where it lies, without a copy
TEST(SceneDataTest, ImagesDecode) {
  const scene message = FixtureScenes().at(0);
  const cv::Mat color = DecodeImage(message.color, "color");
  cv::Mat expected = cv::imdecode(message.color.data, cv::IMREAD_COLOR);
  cv::cvtColor(expected, expected, cv::COLOR_BGR2RGB);
  ASSERT_EQ(color.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(color, expected, cv::NORM_INF), 0);
  const cv::Mat ids = DecodeImage(message.instance_map, "instance_map");
  EXPECT_EQ(ids.type(), CV_16UC1);

  image raw = message.instance_map;
  raw.encoding = image::ENCODING_RAW;
  raw.data.assign(ids.datastart, ids.dataend);
  raw.size = static_cast<int32_t>(raw.data.size());
  const cv::Mat view = DecodeImage(raw, "instance_map");
  EXPECT_EQ(view.data, raw.data.data());
  EXPECT_EQ(cv::norm(view, ids, cv::NORM_INF), 0);

  image broken = message.color;
  broken.data.resize(broken.data.size() / 2);
  broken.size = static_cast<int32_t>(broken.data.size());
  try {
    DecodeImage(broken, "color");
    ADD_FAILURE() << "a PNG cut in half decoded";
  } catch (const FeedError& error) {
    EXPECT_NE(std::string(error.what()).find("color"), std::string::npos) << error.what();
  }
}

// the recorded scenes pass the checks; each one broken in one field fails, the field named
TEST(SceneDataTest, CheckFeedSceneNamesTheField) {
  const std::vector<scene> scenes = FixtureScenes();
  ASSERT_EQ(scenes.size(), 4u);
  std::string why;
  for (const scene& message : scenes) EXPECT_TRUE(CheckFeedScene(message, &why)) << why;

  const std::vector<std::pair<std::string, std::function<void(scene&)>>> breaks = {
      {"instances[1].instance_id", [](scene& s) { s.instances[1].instance_id = 0; }},
      {"instances[2].instance_id",
       [](scene& s) { s.instances[2].instance_id = s.instances[0].instance_id; }},
      {"instances[0].mask_visib_rle", [](scene& s) { s.instances[0].px_count_visib -= 1; }},
      {"instances[3].mask_obj_rle", [](scene& s) { s.instances[3].mask_obj_rle = "0"; }},
      {"instances[0].bbox_visib", [](scene& s) { s.instances[0].bbox_visib[2] = 1000; }},
      {"instances[4].ignored and instances[4].annotated are both true",
       [](scene& s) {
         s.instances[4].annotated = true;
         s.instances[4].ignored = true;
       }},
      {"instances[0].visib_fract 1.5", [](scene& s) { s.instances[0].visib_fract = 1.5; }},
      {"color.width x color.height 161 x 120", [](scene& s) { s.color.width = 161; }},
      {"no instance_map",
       [](scene& s) {
         s.instance_map.data.clear();
         s.instance_map.size = 0;
       }},
      {"num_instances", [](scene& s) { s.num_instances += 1; }},
      {"camera.fx 0 is not a positive number", [](scene& s) { s.camera.fx = 0; }},
  };
  for (const auto& [field, breaker] : breaks) {
    scene broken = scenes[0];
    breaker(broken);
    why.clear();
    EXPECT_FALSE(CheckFeedScene(broken, &why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
  }
}

}  // namespace
}  // namespace stackgen::feed
