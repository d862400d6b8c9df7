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
