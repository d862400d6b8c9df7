// Each randomisation lever, switched on alone, changes what it should and nothing else; and a
// fixed seed renders the stored golden image.

#include <gtest/gtest.h>

#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <tuple>

#include "gen/annotate/pose.h"
#include "gen/scene/scene_generator.h"
#include "tests/support/golden.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

// which levers are on; everything else is fixed.
struct Levers {
  bool camera = false;
  bool lighting = false;
  bool shadows = false;
  bool appearance = false;
  bool background = false;
  bool sensor = false;
  bool environment = false;
  bool surroundings = false;
  bool detail = false;
  bool sensor_3d = false;
};

// five connectors in the default bin, raw images, with only the given levers on.
LoadedConfig ConfigWith(const Levers& on) {
  std::string text = R"(
    part { mesh: "models/corner_connector.obj"
           collision_mesh: "models/corner_connector_collision.obj" count: 5 )";
  text += on.detail ? "detail: CAST }\n" : "}\n";
  text += "output { image_encoding: RAW }\n";
  if (on.surroundings) {
    text +=
        "surroundings { bin_color_probability: 1 scuffed_bin_probability: 1 table_probability: 1 "
        "}\n";
  }
  text += on.camera ? "camera { tilt_max_deg: 8 }\n"
                    : "camera { distance_jitter_mm: 0 tilt_max_deg: 0 roll_max_deg: 0 }\n";
  text += std::string("lighting { randomize: ") + (on.lighting ? "true" : "false") +
          " shadows: " + (on.shadows ? "true" : "false") + " }\n";
  text += std::string("appearance { randomize: ") + (on.appearance ? "true" : "false") + " }\n";
  if (!on.background) text += "background { kind: PLAIN min: 0.5 max: 0.5 }\n";
  text += std::string("sensor { enabled: ") + (on.sensor ? "true" : "false") + " }\n";
  if (on.sensor_3d) text += "sensor_3d { enabled: true }\n";
  if (!on.environment) {
    text +=
        "rendering { procedural_halls: 1 environment_random_yaw: false "
        "environment_intensity_min: 0.8 environment_intensity_max: 0.8 }\n";
  }
  return ParseConfig(text, "levers.pbtxt", std::string(STACKGEN_SOURCE_DIR) + "/config");
}

// the images and poses of one scene.
struct Frame {
  cv::Mat color, depth, ids;
  cv::Mat depth_sensor;  // empty without a 3D camera
  std::vector<Eigen::Isometry3d> world_from_object;
  Eigen::Isometry3d world_from_camera;
};

cv::Mat RawImage(const image& message, int type) {
  EXPECT_EQ(message.encoding, image::ENCODING_RAW);
  return cv::Mat(message.height, message.width, type, const_cast<uint8_t*>(message.data.data()))
      .clone();
}

Frame Generate(const Levers& on, uint64_t seed = 11) {
  static const std::string cache = testing::MakeTempDir("stackgen-levers-cache");
  SceneGenerator generator(ConfigWith(on), 0, seed, cache);
  const scene out = generator.Generate(0, nullptr);
  Frame frame;
  frame.color = RawImage(out.color, CV_8UC3);
  frame.depth = RawImage(out.depth, CV_16UC1);
  frame.ids = RawImage(out.instance_map, CV_16UC1);
  if (out.depth_sensor.size > 0) frame.depth_sensor = RawImage(out.depth_sensor, CV_16UC1);
  for (const instance& object : out.instances) {
    frame.world_from_object.push_back(FromPoseMessage(object.world_from_object));
  }
  frame.world_from_camera = FromPoseMessage(out.camera.world_from_camera);
  return frame;
}

// pixels (CV_8UC1 255) where the colours of two frames differ.
cv::Mat ColourChanged(const Frame& a, const Frame& b) {
  cv::Mat diff;
  cv::absdiff(a.color, b.color, diff);
  cv::Mat sum;
  cv::transform(diff, sum, cv::Matx13f(1, 1, 1));
  return sum > 0;
}

int Count(const cv::Mat& mask, const cv::Mat& region) {
  cv::Mat both;
  cv::bitwise_and(mask, region, both);
  return cv::countNonZero(both);
}

bool Same(const cv::Mat& a, const cv::Mat& b) {
  const cv::Mat differs = a != b;
  return cv::countNonZero(differs.reshape(1)) == 0;
}

// regions of the fixed frame: background, bin (drawn, not an object), objects; and their
// interiors, without the pixels on an edge between them, where anti-aliasing blends the colours
// of both sides
struct Regions {
  cv::Mat background, bin, objects;
  cv::Mat background_inside, bin_inside, objects_inside;
  explicit Regions(const Frame& f) {
    background = f.depth == 0;
    objects = f.ids > 0;
    bin = (f.depth > 0) & (f.ids == 0);
    // an object's interior also leaves out its edges with other objects
    cv::Mat object_edges;
    cv::Mat ids_max, ids_min;
    cv::dilate(f.ids, ids_max, cv::Mat());
    cv::erode(f.ids, ids_min, cv::Mat());
    object_edges = ids_max != ids_min;
    cv::erode(background, background_inside, cv::Mat());
    cv::erode(bin, bin_inside, cv::Mat());
    cv::erode(objects, objects_inside, cv::Mat());
    objects_inside &= ~object_edges;
  }
};

class LeversTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { fixed_ = new Frame(Generate(Levers{})); }
  static void TearDownTestSuite() { delete fixed_; }
  static const Frame& fixed() { return *fixed_; }

  // the geometry (poses, depth, instance map) is untouched
  static void ExpectSameGeometry(const Frame& f) {
    ASSERT_EQ(f.world_from_object.size(), fixed().world_from_object.size());
    for (size_t i = 0; i < f.world_from_object.size(); ++i) {
      EXPECT_TRUE(f.world_from_object[i].isApprox(fixed().world_from_object[i], 0)) << i;
    }
    EXPECT_TRUE(f.world_from_camera.isApprox(fixed().world_from_camera, 0));
    EXPECT_TRUE(Same(f.depth, fixed().depth));
    EXPECT_TRUE(Same(f.ids, fixed().ids));
  }

  // with the levers `on`, the geometry is untouched and the colour changes in more than half of
  // each region named true, and nowhere inside the others (edges, where anti-aliasing blends two
  // regions, are left out there)
  static void ExpectColourChangesOnlyIn(const Levers& on, bool background, bool bin, bool objects) {
    const Frame f = Generate(on);
    ExpectSameGeometry(f);
    const Regions r(fixed());
    const cv::Mat changed = ColourChanged(fixed(), f);
    const std::tuple<const char*, bool, const cv::Mat*, const cv::Mat*> regions[] = {
        {"background", background, &r.background, &r.background_inside},
        {"bin", bin, &r.bin, &r.bin_inside},
        {"objects", objects, &r.objects, &r.objects_inside}};
    for (const auto& [name, changes, whole, inside] : regions) {
      if (changes) {
        EXPECT_GT(Count(changed, *whole), cv::countNonZero(*whole) / 2) << name;
      } else {
        EXPECT_EQ(Count(changed, *inside), 0) << name;
      }
    }
  }

 private:
  static Frame* fixed_;
};

Frame* LeversTest::fixed_ = nullptr;

// the fixed scene has background, bin and objects in view, and repeats exactly
TEST_F(LeversTest, FixedSceneRepeats) {
  const Regions r(fixed());
  EXPECT_GT(cv::countNonZero(r.background), 1000);
  EXPECT_GT(cv::countNonZero(r.bin), 1000);
  EXPECT_GT(cv::countNonZero(r.objects), 1000);
  const Frame again = Generate(Levers{});
  ExpectSameGeometry(again);
  EXPECT_TRUE(Same(again.color, fixed().color));
}

// the background lever changes background pixels only
TEST_F(LeversTest, BackgroundChangesOnlyBackground) {
  Levers on;
  on.background = true;
  ExpectColourChangesOnlyIn(on, true, false, false);
}

// the lighting lever changes the lit surfaces (bin and objects), not the background
TEST_F(LeversTest, LightingChangesOnlySurfaces) {
  Levers on;
  on.lighting = true;
  ExpectColourChangesOnlyIn(on, false, true, true);
}

// the environment lever (which environment, its turn and strength) changes the lit surfaces,
// not the background
TEST_F(LeversTest, EnvironmentChangesOnlySurfaces) {
  Levers on;
  on.environment = true;
  ExpectColourChangesOnlyIn(on, false, true, true);
}

// the surroundings lever restyles the bin and puts a table or belt where the background was: the
// parts' pixels, their ids and their depth stay as they were
TEST_F(LeversTest, SurroundingsChangeOnlyBinAndBackground) {
  Levers on;
  on.surroundings = true;
  const Frame f = Generate(on);
  const Regions r(fixed());
  EXPECT_TRUE(Same(f.ids, fixed().ids));
  cv::Mat depth_changed = f.depth != fixed().depth;
  EXPECT_EQ(Count(depth_changed, ~r.background), 0);
  EXPECT_EQ(Count(f.depth > 0, r.background), cv::countNonZero(r.background)) << "no table";
  const cv::Mat changed = ColourChanged(fixed(), f);
  EXPECT_EQ(Count(changed, r.objects_inside), 0);
  EXPECT_GT(Count(changed, r.bin), cv::countNonZero(r.bin) / 2);
  EXPECT_GT(Count(changed, r.background), cv::countNonZero(r.background) / 2);
}

// procedural detail (here CAST) varies the parts' surfaces alone
TEST_F(LeversTest, DetailChangesOnlyParts) {
  Levers on;
  on.detail = true;
  ExpectColourChangesOnlyIn(on, false, false, true);
}

// shadows only darken lit surfaces: never a brighter pixel, never the background or the ids
TEST_F(LeversTest, ShadowsOnlyDarken) {
  Levers lit;
  lit.lighting = true;
  Levers shadowed = lit;
  shadowed.shadows = true;
  const Frame a = Generate(lit);
  const Frame b = Generate(shadowed);
  ExpectSameGeometry(a);
  ExpectSameGeometry(b);
  cv::Mat a_gray, b_gray;
  cv::cvtColor(a.color, a_gray, cv::COLOR_RGB2GRAY);
  cv::cvtColor(b.color, b_gray, cv::COLOR_RGB2GRAY);
  const Regions r(fixed());
  const cv::Mat darker = b_gray < a_gray;
  const cv::Mat brighter = b_gray > a_gray;
  EXPECT_EQ(Count(darker | brighter, r.background_inside), 0);
  EXPECT_EQ(cv::countNonZero(brighter), 0);
  const int surface = cv::countNonZero(r.bin | r.objects);
  EXPECT_GT(cv::countNonZero(darker), surface / 100) << "no visible shadow";
}

// the appearance lever changes the parts' pixels, not the bin's or the background's
TEST_F(LeversTest, AppearanceChangesOnlyParts) {
  Levers on;
  on.appearance = true;
  ExpectColourChangesOnlyIn(on, false, false, true);
}

// the camera lever moves the camera: the pile is the same, the view of it is not
TEST_F(LeversTest, CameraMovesOnlyTheCamera) {
  Levers on;
  on.camera = true;
  const Frame f = Generate(on);
  ASSERT_EQ(f.world_from_object.size(), fixed().world_from_object.size());
  for (size_t i = 0; i < f.world_from_object.size(); ++i) {
    EXPECT_TRUE(f.world_from_object[i].isApprox(fixed().world_from_object[i], 0)) << i;
  }
  EXPECT_FALSE(f.world_from_camera.isApprox(fixed().world_from_camera, 1e-6));
  EXPECT_GT(cv::countNonZero(f.ids != fixed().ids), 1000);
}

// sensor effects change the image everywhere, but never depth or the instance map
TEST_F(LeversTest, SensorChangesOnlyTheColourImage) {
  Levers on;
  on.sensor = true;
  const Frame f = Generate(on);
  ExpectSameGeometry(f);
  const Regions r(fixed());
  const cv::Mat changed = ColourChanged(fixed(), f);
  EXPECT_GT(Count(changed, r.background), cv::countNonZero(r.background) / 10);
  EXPECT_GT(Count(changed, r.objects), cv::countNonZero(r.objects) / 10);
}

// the 3D camera adds its own depth and changes nothing else: colour, exact depth, ids and poses
// stay byte-identical; its depth has holes on the parts and the bin (shadows, dropout), none
// where nothing was drawn, and elsewhere lies within a few millimetres of the exact depth
TEST_F(LeversTest, DepthSensorAddsItsDepthAndChangesNothingElse) {
  EXPECT_TRUE(fixed().depth_sensor.empty());
  Levers on;
  on.sensor_3d = true;
  const Frame f = Generate(on);
  ExpectSameGeometry(f);
  EXPECT_TRUE(Same(f.color, fixed().color));
  ASSERT_FALSE(f.depth_sensor.empty());
  const Regions r(fixed());
  const cv::Mat holes = f.depth_sensor == 0;
  EXPECT_EQ(Count(holes, r.background), cv::countNonZero(r.background));
  EXPECT_GT(Count(holes, r.objects), 0) << "no dropout on the parts";
  EXPECT_GT(Count(holes, r.bin), 0) << "no shadow on the bin";
  EXPECT_LT(cv::countNonZero(holes & (f.depth > 0)), cv::countNonZero(f.depth > 0) / 2);
  // depth_scale 0.1 mm: 50 counts are 5 mm
  cv::Mat error;
  cv::absdiff(f.depth_sensor, f.depth, error);
  const cv::Mat measured = f.depth_sensor > 0;
  const int near = Count(error <= 50, measured);
  EXPECT_GT(near, cv::countNonZero(measured) * 0.98);
}

// every lever on (the shipped defaults): a fixed seed renders the stored image within a small
// tolerance on llvmpipe; on failure the diff image is written and named.
// STACKGEN_UPDATE_GOLDEN=1 rewrites the golden image.
TEST(GoldenSceneTest, DefaultConfigMatchesGolden) {
  const std::string cache = testing::MakeTempDir("stackgen-golden-cache");
  LoadedConfig config = LoadConfig(std::string(STACKGEN_SOURCE_DIR) + "/config/default.pbtxt");
  config.config.mutable_output()->set_image_encoding(config::OutputConfig::RAW);
  SceneGenerator generator(config, 0, 2024, cache);
  const scene out = generator.Generate(0, nullptr);
  cv::Mat bgr;
  cv::cvtColor(RawImage(out.color, CV_8UC3), bgr, cv::COLOR_RGB2BGR);

  testing::ExpectMatchesGolden(bgr, "scene/default_seed2024_golden.png", "scene_golden");
}

}  // namespace
}  // namespace stackgen
