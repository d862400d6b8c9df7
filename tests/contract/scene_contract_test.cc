#include "contract/scene_contract.h"

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/scene.hpp>

#include "bus/channels.h"
#include "bus/log.h"

namespace stackgen {
namespace {

// The id limits every consumer shares: generator ids 0..65535, seqs 0..99999998.
TEST(SceneContractTest, IdsInRange) {
  EXPECT_TRUE(SceneIdsInRange(0, 0));
  EXPECT_TRUE(SceneIdsInRange(65535, 99999998));
  EXPECT_FALSE(SceneIdsInRange(65536, 0));
  EXPECT_FALSE(SceneIdsInRange(-1, 0));
  EXPECT_FALSE(SceneIdsInRange(0, -1));
  EXPECT_FALSE(SceneIdsInRange(0, 99999999));
}

// A mask's pixels: a COCO compressed RLE string (cocoapi's rleToString) over the whole image;
// one that is empty, malformed or covers another area is refused with the reason.
TEST(SceneContractTest, MaskPixels) {
  std::string why;
  // runs 2 0s, 3 1s, 1 0 over a 6-pixel image: "2", "3", "1" each one char ('0' + n)
  EXPECT_EQ(MaskPixels("231", 6, &why), 3) << why;
  EXPECT_EQ(MaskPixels("6", 6, &why), 0) << why;
  EXPECT_EQ(MaskPixels("231", 7, &why), -1);
  EXPECT_EQ(why, "covers 6 pixels, the image has 7");
  EXPECT_EQ(MaskPixels("", 6, &why), -1);
  EXPECT_EQ(why, "is empty");
  EXPECT_EQ(MaskPixels("2\x7f", 6, &why), -1);
  EXPECT_EQ(why.rfind("is not a COCO RLE string: ", 0), 0u) << why;
  EXPECT_EQ(MaskPixels("231", 7, nullptr), -1);
}

// The recorded scenes of the real generator (tests/fixtures/logs/tiny.lcmlog) keep the contract;
// each kind of break is refused with the field named. Depth and the instance map are checked
// when sent, not required (the feed requires the map: CheckFeedScene).
TEST(SceneContractTest, CheckSceneNamesTheField) {
  std::vector<scene> scenes;
  ReadLog(std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog",
          [&](const LogEvent& event) {
            if (event.channel == kSceneChannel) scenes.push_back(DecodeLogEvent<scene>(event));
          });
  ASSERT_EQ(scenes.size(), 4u);
  ASSERT_GT(scenes[0].num_suction_grasps, 2) << "the fixture has suction grasps";
  ASSERT_GT(scenes[0].num_jaw_grasps, 0) << "the fixture has parallel-jaw grasps";
  ASSERT_GT(scenes[0].depth_sensor.size, 0) << "the fixture has a 3D camera's depth";
  std::string why;
  for (const scene& message : scenes) EXPECT_TRUE(CheckScene(message, &why)) << why;
  scene without_extras = scenes[0];
  without_extras.depth = image{};
  without_extras.instance_map = image{};
  EXPECT_TRUE(CheckScene(without_extras, &why)) << why;

  const std::vector<std::pair<std::string, std::function<void(scene&)>>> breaks = {
      {"header.generator_id 70000", [](scene& s) { s.header.generator_id = 70000; }},
      {"header.seq -1", [](scene& s) { s.header.seq = -1; }},
      {"camera.depth_scale_mm", [](scene& s) { s.camera.depth_scale_mm = -1; }},
      {"camera.world_from_camera.rotation[4] is not finite",
       [](scene& s) { s.camera.world_from_camera.rotation[4] = 1.0 / 0.0; }},
      {"the scene has no color image",
       [](scene& s) {
         s.color.data.clear();
         s.color.size = 0;
       }},
      {"depth.pixel_format", [](scene& s) { s.depth.pixel_format = image::PIXEL_RGB8; }},
      {"depth_sensor.pixel_format",
       [](scene& s) { s.depth_sensor.pixel_format = image::PIXEL_INSTANCE16; }},
      {"suction_grasps[0].instance_id 999",
       [](scene& s) { s.suction_grasps[0].instance_id = 999; }},
      {"suction_grasps[1].normal has length",
       [](scene& s) { s.suction_grasps[1].normal[0] += 0.1; }},
      {"suction_grasps[0].seal 1.5", [](scene& s) { s.suction_grasps[0].seal = 1.5; }},
      {"suction_grasps[2].u, v", [](scene& s) { s.suction_grasps[2].v = s.camera.height; }},
      {"suction_grasps[0].proof 7", [](scene& s) { s.suction_grasps[0].proof = 7; }},
      {"num_suction_grasps", [](scene& s) { s.num_suction_grasps += 1; }},
      {"jaw_grasps[0].instance_id 999", [](scene& s) { s.jaw_grasps[0].instance_id = 999; }},
      {"jaw_grasps[0].approach has length", [](scene& s) { s.jaw_grasps[0].approach[2] *= 2; }},
      {"jaw_grasps[0].width_mm -1", [](scene& s) { s.jaw_grasps[0].width_mm = -1; }},
      {"num_jaw_grasps", [](scene& s) { s.num_jaw_grasps = -1; }},
      {"instance_map.data: ", [](scene& s) { s.instance_map.data[1] ^= 0xff; }},
      {"color.size 1", [](scene& s) { s.color.size = 1; }},
      {"instances[1].class_name is empty", [](scene& s) { s.instances[1].class_name.clear(); }},
      {"instances[0].posture_deg[2] is not finite",
       [](scene& s) { s.instances[0].posture_deg[2] = 0.0 / 0.0; }},
      {"instances[2].px_count_visib", [](scene& s) { s.instances[2].px_count_visib = -1; }},
      {"instances[0].mask_obj_rle holds", [](scene& s) { s.instances[0].px_count_all += 1; }},
      {"instances[0].bbox_visib [-1,", [](scene& s) { s.instances[0].bbox_visib[0] = -1; }},
      // the whole silhouette may reach past the image by the image's size, not further
      {"instances[0].bbox_obj [-",
       [](scene& s) { s.instances[0].bbox_obj[0] = -s.camera.width - 1; }},
      // past the image, the mask may hold fewer pixels than px_count_all, never more
      {"instances[0].mask_obj_rle holds",
       [](scene& s) {
         s.instances[0].bbox_obj[1] = -5;
         s.instances[0].px_count_all -= 1;
       }},
  };
  // an object cut by the image's edge: its box starts outside, px_count_all counts the part there
  scene cut = scenes[0];
  cut.instances[0].bbox_obj[0] = -30;
  cut.instances[0].bbox_obj[2] += 30;
  cut.instances[0].px_count_all += 500;
  EXPECT_TRUE(CheckScene(cut, &why)) << why;

  for (const auto& [field, breaker] : breaks) {
    scene broken = scenes[0];
    breaker(broken);
    why.clear();
    EXPECT_FALSE(CheckScene(broken, &why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
  }
}

}  // namespace
}  // namespace stackgen
