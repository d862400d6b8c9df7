#include "gen/scene/scene_generator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <future>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <string>
#include <vector>

#include "gen/annotate/pose.h"
#include "gen/annotate/rle.h"
#include "gen/physics/pile.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

LoadedConfig DefaultConfig() {
  return LoadConfig(std::string(STACKGEN_SOURCE_DIR) + "/config/default.pbtxt");
}

cv::Mat DecodeImage(const image& message, int flags) {
  EXPECT_EQ(message.encoding, image::ENCODING_PNG);
  return cv::imdecode(message.data, flags);
}

// seeds of neighbouring scenes, generators and redraws all differ.
TEST(SceneGeneratorTest, SeedsDiffer) {
  std::set<uint64_t> seeds;
  for (int g = 0; g < 4; ++g) {
    for (int k = 0; k < 50; ++k) {
      for (int r = 0; r < 3; ++r) seeds.insert(SceneSeed(1, g, k, r));
    }
  }
  EXPECT_EQ(seeds.size(), 4u * 50 * 3);
  EXPECT_EQ(SceneSeed(5, 1, 2, 0), SceneSeed(5, 1, 2, 0));
}

// one scene of the default config: the images, the instance map and the labels agree, and the
// same seq gives bit-identical labels again.
TEST(SceneGeneratorTest, SceneIsConsistentAndRepeatable) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  SceneGenerator generator(DefaultConfig(), 0, 42, cache);
  StageTimes times;
  const scene first = generator.Generate(0, &times);
  EXPECT_GT(times.physics_ms, 0);

  // header and camera.
  EXPECT_EQ(first.header.seq, 0);
  EXPECT_EQ(first.header.generator_id, 0);
  EXPECT_EQ(first.num_instances, 12);
  ASSERT_EQ(first.instances.size(), 12u);
  EXPECT_EQ(first.camera.width, 640);
  EXPECT_EQ(first.camera.height, 480);

  // the images decode to the camera's size.
  const cv::Mat color = DecodeImage(first.color, cv::IMREAD_UNCHANGED);
  const cv::Mat depth = DecodeImage(first.depth, cv::IMREAD_UNCHANGED);
  const cv::Mat ids = DecodeImage(first.instance_map, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(color.size(), cv::Size(640, 480));
  EXPECT_EQ(color.type(), CV_8UC3);
  ASSERT_EQ(depth.type(), CV_16UC1);
  ASSERT_EQ(ids.type(), CV_16UC1);

  // every instance's mask is exactly its pixels in the instance map.
  int annotated = 0;
  for (const instance& object : first.instances) {
    const cv::Mat from_map = ids == object.instance_id;
    EXPECT_EQ(cv::countNonZero(from_map), object.px_count_visib);
    const cv::Mat from_rle = DecodeRle(object.mask_visib_rle, 480, 640);
    EXPECT_EQ(cv::countNonZero(from_rle != from_map), 0) << "instance " << object.instance_id;
    EXPECT_GE(object.px_count_all, object.px_count_visib);
    EXPECT_LE(object.visib_fract, 1.0);
    if (object.annotated) ++annotated;
    // objects lie in the bin: below the rim plus one part height, above the floor.
    EXPECT_LT(object.world_from_object.translation_mm[2], 100 + 60);
    EXPECT_GT(object.world_from_object.translation_mm[2], -1);
  }
  EXPECT_GT(annotated, 0);

  // visible part pixels, back-projected with their depth (mm = value * scale), lie between the
  // floor and the rim plus one part height in the bin frame
  const Eigen::Isometry3d world_from_camera = FromPoseMessage(first.camera.world_from_camera);
  double lowest = 1e9, highest = -1e9;
  for (int v = 0; v < ids.rows; ++v) {
    for (int u = 0; u < ids.cols; ++u) {
      if (ids.at<uint16_t>(v, u) == 0) continue;
      const double mm = depth.at<uint16_t>(v, u) * first.camera.depth_scale_mm;
      const Eigen::Vector3d in_camera((u - first.camera.cx) * mm / first.camera.fx,
                                      (v - first.camera.cy) * mm / first.camera.fy, mm);
      const double z = (world_from_camera * in_camera).z();
      lowest = std::min(lowest, z);
      highest = std::max(highest, z);
    }
  }
  EXPECT_GT(lowest, -1.0);
  EXPECT_LT(highest, 100 + 60);

  // the same scene again is bit-identical in its labels.
  const scene again = generator.Generate(0, nullptr);
  ASSERT_EQ(again.instances.size(), first.instances.size());
  for (size_t i = 0; i < first.instances.size(); ++i) {
    for (int j = 0; j < 3; ++j) {
      EXPECT_EQ(again.instances[i].world_from_object.translation_mm[j],
                first.instances[i].world_from_object.translation_mm[j]);
    }
    EXPECT_EQ(again.instances[i].mask_visib_rle, first.instances[i].mask_visib_rle);
  }
  EXPECT_EQ(again.header.seed, first.header.seed);

  // labels carry the same header and instances.
  const labels small = LabelsOf(first);
  EXPECT_EQ(small.header.seed, first.header.seed);
  EXPECT_EQ(small.num_instances, first.num_instances);
}

// the pipeline: piles settled on a second thread while scenes are finished on this one give
// the same scenes as Generate, byte for byte (labels and images)
TEST(SceneGeneratorTest, PilesSettledOnAnotherThreadGiveTheSameScenes) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  SceneGenerator generator(DefaultConfig(), 3, 7, cache);
  std::vector<std::vector<uint8_t>> pipelined;
  std::future<SettledPile> ahead =
      std::async(std::launch::async, [&generator] { return generator.Settle(0); });
  for (int64_t seq = 0; seq < 3; ++seq) {
    const SettledPile settled = ahead.get();
    EXPECT_EQ(settled.pile, seq);
    ahead = std::async(std::launch::async, [&generator, seq] { return generator.Settle(seq + 1); });
    scene message = generator.Finish(settled, seq, nullptr);
    pipelined.push_back(std::vector<uint8_t>(message.getEncodedSize()));
    message.encode(pipelined.back().data(), 0, static_cast<int>(pipelined.back().size()));
  }
  ahead.wait();
  for (int64_t seq = 0; seq < 3; ++seq) {
    scene message = generator.Generate(seq, nullptr);
    std::vector<uint8_t> bytes(message.getEncodedSize());
    message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
    EXPECT_TRUE(bytes == pipelined[seq]) << "scene " << seq;
  }
}

// the bytes of a scene message
std::vector<uint8_t> Encoded(scene message) {
  std::vector<uint8_t> bytes(message.getEncodedSize());
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return bytes;
}

// views_per_pile 3: scenes 0, 1, 2 show one pile (the same poses) from different cameras with
// their own seeds, scene 3 the next pile; view 0 is the scene a single view makes, and a view
// made from a pile settled for another view of it is the same as Generate's
TEST(SceneGeneratorTest, ViewsOfOnePile) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  LoadedConfig config = DefaultConfig();
  SceneGenerator single(config, 1, 9, cache);
  config.config.mutable_physics()->set_views_per_pile(3);
  SceneGenerator views(config, 1, 9, cache);
  EXPECT_EQ(views.views_per_pile(), 3);
  const SettledPile pile = views.Settle(1);
  EXPECT_EQ(pile.pile, 0);
  std::vector<scene> scenes;
  for (int64_t seq = 0; seq < 3; ++seq) scenes.push_back(views.Finish(pile, seq, nullptr));
  scenes.push_back(views.Generate(3, nullptr));
  std::set<int64_t> seeds;
  for (size_t k = 0; k < scenes.size(); ++k) {
    EXPECT_EQ(scenes[k].header.seq, static_cast<int64_t>(k));
    seeds.insert(scenes[k].header.seed);
    ASSERT_EQ(scenes[k].instances.size(), 12u);
  }
  EXPECT_EQ(seeds.size(), 4u);
  for (size_t i = 0; i < 12; ++i) {
    const double* first = scenes[0].instances[i].world_from_object.translation_mm;
    for (int k = 1; k < 3; ++k) {
      const double* same = scenes[k].instances[i].world_from_object.translation_mm;
      EXPECT_TRUE(std::equal(first, first + 3, same)) << "view " << k << " instance " << i;
    }
  }
  const double* next = scenes[3].instances[0].world_from_object.translation_mm;
  EXPECT_FALSE(std::equal(next, next + 3, scenes[0].instances[0].world_from_object.translation_mm));
  EXPECT_FALSE(std::equal(scenes[0].camera.world_from_camera.translation_mm,
                          scenes[0].camera.world_from_camera.translation_mm + 3,
                          scenes[1].camera.world_from_camera.translation_mm));
  EXPECT_TRUE(Encoded(scenes[0]) == Encoded(single.Generate(0, nullptr)));
  EXPECT_TRUE(Encoded(scenes[2]) == Encoded(views.Generate(2, nullptr)));
  EXPECT_THROW(views.Finish(pile, 3, nullptr), std::invalid_argument);
}

// pick_sequence with 4 parts and 2 views: pile 0 shows 4, 3, 2, 1 and 0 parts, two scenes each,
// then pile 1 starts at scene 10 with 4 again; the empty bin is a scene without instances;
// states made one after the other (the pipeline) give the same scenes as Generate, which picks
// from scratch
TEST(SceneGeneratorTest, PickSequenceEmptiesTheBin) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  LoadedConfig config = DefaultConfig();
  config.config.mutable_part(0)->set_count(4);
  config.config.mutable_physics()->set_views_per_pile(2);
  config.config.mutable_physics()->set_pick_sequence(true);
  SceneGenerator generator(config, 2, 5, cache);
  const ScenePlace place = generator.PlaceOf(7);
  EXPECT_EQ(place.pile, 0);
  EXPECT_EQ(place.level, 3);
  EXPECT_EQ(place.view, 1);
  EXPECT_EQ(place.first_seq, 6);
  EXPECT_EQ(generator.PlaceOf(10).pile, 1);
  EXPECT_EQ(generator.PlaceOf(10).level, 0);

  SettledPile state = generator.Settle(0);
  std::vector<std::vector<uint8_t>> pipelined;
  for (int level = 0; level <= 5; ++level) {
    ASSERT_EQ(state.first_seq, 2 * level);
    ASSERT_EQ(state.pile, level < 5 ? 0 : 1);
    ASSERT_EQ(state.object_types.size(), level < 5 ? 4u - level : 4u);
    for (int64_t seq = state.first_seq; seq < state.first_seq + 2; ++seq) {
      pipelined.push_back(Encoded(generator.Finish(state, seq, nullptr)));
    }
    if (level == 5) break;
    const SettledPile next = generator.SettleNext(state);
    if (level < 4) {
      EXPECT_NE(next.seed, state.seed);
    }
    state = next;
  }
  const scene empty = generator.Generate(8, nullptr);
  EXPECT_EQ(empty.num_instances, 0);
  EXPECT_FALSE(empty.color.data.empty());
  for (int64_t seq : {1, 5, 8, 11}) {
    EXPECT_TRUE(Encoded(generator.Generate(seq, nullptr)) == pipelined[seq]) << "scene " << seq;
  }
  EXPECT_THROW(generator.Finish(state, 9, nullptr), std::invalid_argument);
}

// picks with proven grasps: each pick takes a part a cup lifted from above when one of the first
// parts in picking order could be (the proof runs again to the same end from the state before),
// else the topmost as before; the same states however the piles are reached
TEST(SceneGeneratorTest, PicksTakeWhereTheProofLifted) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  LoadedConfig config = DefaultConfig();
  config.config.mutable_part(0)->set_count(5);
  config.config.mutable_physics()->set_pick_sequence(true);
  config::GraspConfig& grasps = *config.config.mutable_grasps();
  grasps.set_suction(true);
  grasps.set_prove_per_part(2);
  grasps.set_prove_parts(3);
  SceneGenerator generator(config, 0, 3, cache);
  LiftParams lift;
  lift.cup_diameter_mm = grasps.cup_diameter_mm();
  SettledPile state = generator.Settle(0);
  EXPECT_EQ(state.picked, -1);
  int proven = 0;
  for (int level = 1; level < 5; ++level) {
    const SettledPile next = generator.SettleNext(state);
    ASSERT_EQ(next.level, level);
    ASSERT_GE(next.picked, 0);
    const std::vector<int> order =
        generator.simulator().PickOrder(state.object_types, state.world_from_object);
    if (next.picked_proven) {
      ++proven;
      const LiftResult again =
          generator.simulator().Lift(state.object_types, state.world_from_object, next.picked,
                                     next.picked_point_mm, next.picked_normal, lift);
      EXPECT_EQ(again.outcome, LiftResult::Outcome::kLifted) << "level " << level;
    } else {
      EXPECT_EQ(next.picked, order[0]) << "level " << level;
    }
    EXPECT_EQ(generator.Settle(next.first_seq).world_from_object.size(),
              next.world_from_object.size());
    state = next;
  }
  EXPECT_GT(proven, 0);
}

// config/cut_and_paste.pbtxt: no physics and no bin: 12 parts at random places over the floor,
// 10..60 mm up, as a pure function of the seed; the floor area shows the background (nothing
// drawn there), and the parts still get exact labels
TEST(SceneGeneratorTest, CutAndPastePlacesPartsWithoutPhysicsOrBin) {
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  const LoadedConfig config =
      LoadConfig(std::string(STACKGEN_SOURCE_DIR) + "/config/cut_and_paste.pbtxt");
  SceneGenerator generator(config, 0, 4, cache);
  StageTimes times;
  const scene first = generator.Generate(0, &times);
  ASSERT_EQ(first.instances.size(), 12u);
  EXPECT_EQ(times.redraws, 0);
  for (const instance& object : first.instances) {
    const double* t = object.world_from_object.translation_mm;
    EXPECT_LE(std::abs(t[0]), 100.0);
    EXPECT_LE(std::abs(t[1]), 75.0);
    EXPECT_GE(t[2], 10.0);
    EXPECT_LE(t[2], 60.0);
  }
  // the middle of the image sees parts or the background, never a bin (depth 0 where no part)
  const cv::Mat depth = cv::imdecode(first.depth.data, cv::IMREAD_UNCHANGED);
  const cv::Mat ids = cv::imdecode(first.instance_map.data, cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(depth.empty());
  EXPECT_EQ(cv::countNonZero((depth > 0) & (ids == 0)), 0);
  EXPECT_GT(cv::countNonZero(ids > 0), 1000);
  EXPECT_TRUE(Encoded(first) == Encoded(generator.Generate(0, nullptr)));

  // no pile to pick from
  LoadedConfig picking = config;
  picking.config.mutable_physics()->set_pick_sequence(true);
  EXPECT_THROW(ParseConfig(picking.config.DebugString(), "picking.pbtxt", config.base_dir),
               ConfigError);
}

// The physics of drops that were redrawn is counted apart (stackgen-rest-check prints its share):
// none without a redraw; with drops that did not settle in time (a 1.5 s cap), part of the
// pile's physics, and all of it unsettled here.
TEST(SceneGeneratorTest, RedrawnDropsPhysicsIsCountedApart) {
  LoadedConfig config = DefaultConfig();
  config::PhysicsConfig& physics = *config.config.mutable_physics();
  physics.set_max_sim_time_s(1.5);
  physics.set_settle_translation_mm(1);
  physics.set_settle_rotation_deg(1);
  physics.set_settle_window_s(0.25);
  const SceneGenerator generator(config, 0, 1, testing::MakeTempDir("stackgen-cache"));
  int unsettled = 0;
  for (int64_t seq = 0; seq < 2; ++seq) {
    const StageTimes times = generator.Settle(seq).times;
    unsettled += times.redraws_unsettled;
    EXPECT_EQ(times.redraws, times.redraws_unsettled) << seq;
    if (times.redraws == 0) {
      EXPECT_EQ(times.redrawn_physics_ms, 0) << seq;
      EXPECT_EQ(times.unsettled_physics_ms, 0) << seq;
    } else {
      EXPECT_GT(times.unsettled_physics_ms, 0) << seq;
      EXPECT_EQ(times.unsettled_physics_ms, times.redrawn_physics_ms) << seq;
      EXPECT_LT(times.redrawn_physics_ms, times.physics_ms) << seq;
    }
  }
  EXPECT_GE(unsettled, 1);
}

// a bin too small for the parts is refused before anything runs, naming the config.
TEST(SceneGeneratorTest, BinTooSmallIsRefused) {
  LoadedConfig config = DefaultConfig();
  config.config.mutable_bin()->set_inner_length_mm(40);
  try {
    SceneGenerator generator(config, 0, 1, testing::MakeTempDir("stackgen-cache"));
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& error) {
    EXPECT_NE(std::string(error.what()).find("default.pbtxt"), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("bin"), std::string::npos) << error.what();
  }
  config = DefaultConfig();
  config.config.mutable_part(0)->set_count(200);
  EXPECT_THROW(SceneGenerator(config, 0, 1, testing::MakeTempDir("stackgen-cache")), ConfigError);
}

}  // namespace
}  // namespace stackgen

namespace stackgen {
namespace {

// config/mixed.pbtxt: connectors and pins are labelled as classes 1 and 2 in their count ranges,
// the foam-block distractors fall into the pile and show in the image but never become instances,
// and every instance carries its resting face.
TEST(SceneGeneratorTest, MixedPartsAndDistractors) {
  LoadedConfig config = LoadConfig(std::string(STACKGEN_SOURCE_DIR) + "/config/mixed.pbtxt");
  config.config.mutable_physics()->set_drop_mode(config::PhysicsConfig::RANDOM_VOLUME);
  const std::string cache = testing::MakeTempDir("stackgen-cache");
  SceneGenerator generator(config, 0, 7, cache);
  std::set<std::pair<int, int>> count_pairs;
  int distractor_px = 0;
  for (int seq = 0; seq < 4; ++seq) {
    const scene s = generator.Generate(seq, nullptr);
    int connectors = 0, pins = 0;
    for (const instance& object : s.instances) {
      ASSERT_TRUE(object.class_id == 1 || object.class_id == 2) << object.class_id;
      EXPECT_EQ(object.class_name, object.class_id == 1 ? "corner_connector" : "dowel_pin");
      EXPECT_GE(object.resting_face, 0);
      (object.class_id == 1 ? connectors : pins) += 1;
    }
    EXPECT_GE(connectors, 6);
    EXPECT_LE(connectors, 10);
    EXPECT_GE(pins, 2);
    EXPECT_LE(pins, 6);
    count_pairs.insert({connectors, pins});

    // unlabelled surfaces above the floor in the middle of the bin (no walls there): distractors
    const cv::Mat ids = cv::imdecode(s.instance_map.data, cv::IMREAD_UNCHANGED);
    const cv::Mat depth = cv::imdecode(s.depth.data, cv::IMREAD_UNCHANGED);
    const double floor_depth = 520 / s.camera.depth_scale_mm;
    for (int v = ids.rows / 4; v < 3 * ids.rows / 4; ++v) {
      for (int u = ids.cols / 4; u < 3 * ids.cols / 4; ++u) {
        const uint16_t d = depth.at<uint16_t>(v, u);
        if (ids.at<uint16_t>(v, u) == 0 && d > 0 && d < floor_depth - 5 / s.camera.depth_scale_mm) {
          ++distractor_px;
        }
      }
    }
  }
  EXPECT_GT(count_pairs.size(), 1u) << "the counts never varied";
  EXPECT_GT(distractor_px, 200);
}

}  // namespace
}  // namespace stackgen
