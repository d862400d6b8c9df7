// The 3D camera of gen/randomize/depth_sensor.cc with the renderer's projector return: the
// projector's shadow against geometry, specular dropout on polished metal, the noise law, flying
// pixels, resolution, and the exact depth left as it was.
#include "gen/randomize/depth_sensor.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "gen/render/renderer.h"
#include "tests/support/cameras.h"
#include "tests/support/meshes.h"

namespace stackgen {
namespace {

constexpr double kHeightMm = 500;  // the camera above the z = 0 plane
constexpr double kBaselineMm = 100;

// a camera kHeightMm above the z = 0 plane, looking straight down
CameraModel CameraLookingDown(int width = 320, int height = 240) {
  return testing::CameraLookingDown(kHeightMm, width, height);
}

DrawItem Item(int mesh_id, const Eigen::Vector3d& at, float metallic, float roughness,
              float gray, uint16_t id) {
  DrawItem item;
  item.mesh_id = mesh_id;
  item.world_from_object = Eigen::Translation3d(at) * Eigen::Isometry3d::Identity();
  item.instance_id = id;
  item.material.color = Eigen::Vector3f::Constant(gray);
  item.material.metal_color = Eigen::Vector3f::Constant(gray);
  item.material.metallic = metallic;
  item.material.roughness = roughness;
  return item;
}

// what the renderer gives the sensor: the camera's frame with the projector's return, and
// where the projector lights the surface
struct SensorInputs {
  RenderResult frame;
  cv::Mat visible;
};

SensorInputs RenderForSensor(Renderer* renderer, const CameraModel& camera,
                             const std::vector<DrawItem>& items) {
  RenderOptions options;
  options.shading = Shading::kPbr;
  options.msaa_samples = 1;
  options.projector_return = true;
  options.projector_position_mm =
      camera.world_from_camera * Eigen::Vector3d(kBaselineMm, 0, 0);
  SensorInputs in;
  in.frame = renderer->Render(camera, {}, options, items);
  double nearest = 1e9;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const float z = in.frame.depth_mm.at<float>(v, u);
      if (z > 0) nearest = std::min<double>(nearest, z);
    }
  }
  const CameraModel projector = ProjectorCamera(camera, kBaselineMm, nearest);
  const RenderResult seen = renderer->Render(projector, {}, RenderOptions{}, items);
  in.visible = ProjectorVisible(in.frame.depth_mm, camera, seen.depth_mm, projector, kBaselineMm);
  return in;
}

// no noise, no flying pixels, no rounding: only the holes
DepthSensorModel HolesOnly() {
  DepthSensorModel model;
  model.baseline_mm = kBaselineMm;
  model.noise_at_1m_mm = 0;
  model.flying_pixel_probability = 0;
  model.quantization_mm = 0;
  return model;
}

// the projector's shadow of a box on a plane falls exactly where the line from the floor to the
// projector passes through the box (computed here from the geometry), on the box's side away
// from the projector, and nowhere else
TEST(DepthSensorTest, ProjectorShadowFallsBehindTheBoxAwayFromTheProjector) {
  Renderer renderer(320, 240);
  const int floor_mesh = renderer.AddMesh(testing::MakeSquare(1000));
  const double half = 20, tall = 80;
  const int box_mesh = renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 40, 80)));
  const CameraModel camera = CameraLookingDown();
  const SensorInputs in = RenderForSensor(
      &renderer, camera,
      {Item(floor_mesh, {0, 0, 0}, 0, 0.8f, 0.8f, 0), Item(box_mesh, {0, 0, tall / 2}, 0, 0.8f,
                                                           0.8f, 1)});
  std::mt19937_64 engine(1);
  const cv::Mat depth = SensorDepth(in.frame.depth_mm, in.visible, in.frame.projector_return,
                                    HolesOnly(), engine);

  // the geometry's answer: a floor point is in shadow when the segment to the projector at
  // (baseline, 0, height) enters the box [-half, half]^2 x [0, tall] (slabs)
  const Eigen::Vector3d projector(kBaselineMm, 0, kHeightMm);
  cv::Mat expected(depth.size(), CV_8UC1, cv::Scalar(0));
  int floor_pixels = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      if (in.frame.instance.at<uint16_t>(v, u) != 0) continue;
      ++floor_pixels;
      const double z = in.frame.depth_mm.at<float>(v, u);
      const Eigen::Vector3d p((u - camera.cx) * z / camera.fx, -(v - camera.cy) * z / camera.fy,
                              kHeightMm - z);
      const Eigen::Vector3d d = projector - p;
      double enter = 0, leave = 1;
      const double lo[3] = {-half, -half, 0}, hi[3] = {half, half, tall};
      for (int k = 0; k < 3; ++k) {
        double t0 = (lo[k] - p[k]) / d[k], t1 = (hi[k] - p[k]) / d[k];
        if (t0 > t1) std::swap(t0, t1);
        enter = std::max(enter, t0);
        leave = std::min(leave, t1);
      }
      if (enter < leave) expected.at<uint8_t>(v, u) = 255;
    }
  }
  ASSERT_GT(floor_pixels, 50000);
  const int shadow = cv::countNonZero(expected);
  // about 23 mm x 44 mm of floor, 18 x 35 pixels
  ASSERT_GT(shadow, 400);

  // holes where the geometry says (away from the shadow's outline, one pixel either side),
  // depth everywhere else, and every hole left of the box (world x < -half: away from the
  // projector at +x)
  const cv::Mat kernel = cv::Mat::ones(3, 3, CV_8UC1);
  cv::Mat surely_dark, surely_lit;
  cv::erode(expected, surely_dark, kernel);
  cv::dilate(expected, surely_lit, kernel);
  surely_lit = surely_lit == 0;
  int holes = 0, missed = 0, wrong = 0, astray = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const bool hole = depth.at<float>(v, u) == 0;
      holes += hole;
      if (surely_dark.at<uint8_t>(v, u) && !hole) ++missed;
      if (surely_lit.at<uint8_t>(v, u) && hole) ++wrong;
      const double x = (u - camera.cx) * kHeightMm / camera.fx;
      if (hole && x > -half) ++astray;
    }
  }
  EXPECT_EQ(missed, 0) << "shadow pixels with depth";
  EXPECT_EQ(wrong, 0) << "lit pixels without depth";
  EXPECT_EQ(astray, 0) << "holes not on the box's side away from the projector";
  EXPECT_GT(holes, shadow * 0.8);
  EXPECT_LT(holes, shadow * 1.2);
}

// a mirror-flat metal plate facing the camera returns none of the pattern but where it mirrors
// the projector into the camera (a saturated glint, with a thin fringe of a few degrees that
// returns a measurable part): no depth on at least 95 % of it; matte plastic
// returns its albedo everywhere: depth on all of it; white paper returns about 1
TEST(DepthSensorTest, PolishedMetalFacingTheCameraDropsOutMattePlasticDoesNot) {
  Renderer renderer(320, 240);
  const int plate = renderer.AddMesh(testing::MakeSquare(300));
  const CameraModel camera = CameraLookingDown();
  struct Case {
    const char* name;
    float metallic, roughness, gray;
    double most_holes, fewest_holes;
  };
  for (const Case& c : {Case{"polished metal", 1, 0.03f, 0.9f, 1.0, 0.95},
                        Case{"matte plastic", 0, 0.7f, 0.5f, 0.0, 0.0}}) {
    SCOPED_TRACE(c.name);
    const SensorInputs in = RenderForSensor(
        &renderer, camera, {Item(plate, {0, 0, 0}, c.metallic, c.roughness, c.gray, 1)});
    std::mt19937_64 engine(1);
    const cv::Mat depth = SensorDepth(in.frame.depth_mm, in.visible, in.frame.projector_return,
                                      HolesOnly(), engine);
    const cv::Mat on_plate = in.frame.instance == 1;
    const int pixels = cv::countNonZero(on_plate);
    ASSERT_GT(pixels, 50000);
    const int holes = cv::countNonZero((depth == 0) & on_plate);
    EXPECT_GE(holes, c.fewest_holes * pixels);
    EXPECT_LE(holes, c.most_holes * pixels);
    EXPECT_EQ(cv::countNonZero(in.visible & on_plate), pixels) << "a plate casts no shadow";
  }

  // white paper facing the projector: a return of about 1
  const SensorInputs in =
      RenderForSensor(&renderer, camera, {Item(plate, {0, 0, 0}, 0, 1.0f, 1.0f, 1)});
  const float centre = in.frame.projector_return.at<float>(120, 160);
  EXPECT_NEAR(centre, 0.97, 0.05);
}

// the 3D camera's pass changes nothing of the colour camera's: depth, ids and colour stay
// byte-identical with the projector's return asked for or not
TEST(DepthSensorTest, ProjectorReturnLeavesTheFrameAsItWas) {
  Renderer renderer(320, 240);
  const int plate = renderer.AddMesh(testing::MakeSquare(300));
  const int box = renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 40, 80)));
  const CameraModel camera = CameraLookingDown();
  const std::vector<DrawItem> items = {Item(plate, {0, 0, 0}, 0, 0.5f, 0.5f, 0),
                                       Item(box, {10, 5, 40}, 1, 0.3f, 0.8f, 1)};
  RenderOptions options;
  options.shading = Shading::kPbr;
  const RenderResult plain = renderer.Render(camera, {}, options, items);
  options.projector_return = true;
  options.projector_position_mm = Eigen::Vector3d(100, 0, 500);
  const RenderResult with = renderer.Render(camera, {}, options, items);
  const auto same = [](const cv::Mat& a, const cv::Mat& b) {
    if (a.size() != b.size() || a.type() != b.type()) return false;
    cv::Mat differs;
    cv::compare(a.reshape(1), b.reshape(1), differs, cv::CMP_NE);
    return cv::countNonZero(differs) == 0;
  };
  EXPECT_TRUE(same(plain.depth_mm, with.depth_mm));
  EXPECT_TRUE(same(plain.instance, with.instance));
  EXPECT_TRUE(same(plain.color_linear, with.color_linear));
  EXPECT_TRUE(plain.projector_return.empty());
  ASSERT_FALSE(with.projector_return.empty());
  EXPECT_GT(cv::countNonZero(with.projector_return > 0), 50000);
}

// a plane at `z_mm` everywhere, lit and returning 0.5
struct Plane {
  cv::Mat depth, visible, back;
  explicit Plane(float z_mm, int size = 200)
      : depth(size, size, CV_32FC1, cv::Scalar(z_mm)),
        visible(size, size, CV_8UC1, cv::Scalar(255)),
        back(size, size, CV_32FC1, cv::Scalar(0.5)) {}
};

// axial noise grows with the square of the distance: its spread at 1 m is four times that at
// 0.5 m (40,000 pixels each, fixed seeds: the spread of a spread is 0.4 %)
TEST(DepthSensorTest, NoiseAtOneMetreIsFourTimesThatAtHalfAMetre) {
  DepthSensorModel model = HolesOnly();
  model.noise_at_1m_mm = 2;
  const auto spread = [&](float z_mm, uint64_t seed) {
    const Plane plane(z_mm);
    std::mt19937_64 engine(seed);
    const cv::Mat depth = SensorDepth(plane.depth, plane.visible, plane.back, model, engine);
    cv::Scalar mean, stddev;
    cv::meanStdDev(depth, mean, stddev);
    EXPECT_NEAR(mean[0], z_mm, 0.05);
    return stddev[0];
  };
  const double near = spread(500, 1), far = spread(1000, 2);
  EXPECT_NEAR(near, 0.5, 0.01);  // 2 mm x 0.5^2
  EXPECT_NEAR(far, 2.0, 0.04);
  EXPECT_NEAR(far / near, 4.0, 0.1);
}

// holes: no exact depth, unlit, too little or too much returned; the rest measured
TEST(DepthSensorTest, HolesWhereUnlitTooDarkOrSaturated) {
  Plane plane(600, 4);
  plane.depth.at<float>(0, 0) = 0;
  plane.visible.at<uint8_t>(0, 1) = 0;
  plane.back.at<float>(0, 2) = 0.01f;
  plane.back.at<float>(0, 3) = 25.f;
  std::mt19937_64 engine(1);
  const cv::Mat depth = SensorDepth(plane.depth, plane.visible, plane.back, HolesOnly(), engine);
  for (int u = 0; u < 4; ++u) EXPECT_EQ(depth.at<float>(0, u), 0.f) << "pixel " << u;
  EXPECT_EQ(cv::countNonZero(depth), 12);
  EXPECT_EQ(depth.at<float>(2, 2), 600.f);
}

// flying pixels: with probability 1, the pixels on both sides of a 100 mm step lie between the
// two depths; every other pixel keeps its exact depth
TEST(DepthSensorTest, FlyingPixelsOnlyAcrossDepthSteps) {
  Plane plane(500, 20);
  plane.depth.colRange(10, 20).setTo(600);
  DepthSensorModel model = HolesOnly();
  model.flying_pixel_probability = 1;
  std::mt19937_64 engine(3);
  const cv::Mat depth = SensorDepth(plane.depth, plane.visible, plane.back, model, engine);
  int between = 0;
  for (int v = 0; v < 20; ++v) {
    for (int u = 0; u < 20; ++u) {
      const float z = depth.at<float>(v, u);
      if (u == 9 || u == 10) {
        EXPECT_GE(z, 500.f);
        EXPECT_LE(z, 600.f);
        between += z != 500.f && z != 600.f;
      } else {
        EXPECT_EQ(z, plane.depth.at<float>(v, u)) << u << ", " << v;
      }
    }
  }
  EXPECT_EQ(between, 40);
}

// the sensor's resolution: depths in quantization_mm steps, one value per subsample block
TEST(DepthSensorTest, QuantisedAndSubsampled) {
  Plane plane(500, 8);
  for (int v = 0; v < 8; ++v) {
    for (int u = 0; u < 8; ++u) plane.depth.at<float>(v, u) = 500.f + 0.13f * (8 * v + u);
  }
  DepthSensorModel model = HolesOnly();
  model.quantization_mm = 1;
  model.subsample = 4;
  std::mt19937_64 engine(1);
  const cv::Mat depth = SensorDepth(plane.depth, plane.visible, plane.back, model, engine);
  for (int v = 0; v < 8; ++v) {
    for (int u = 0; u < 8; ++u) {
      // the block's centre pixel (2, 2) of each 4 x 4 block, rounded to whole millimetres
      const float centre = plane.depth.at<float>(v / 4 * 4 + 2, u / 4 * 4 + 2);
      EXPECT_EQ(depth.at<float>(v, u), std::round(centre)) << u << ", " << v;
    }
  }
}

// the projector's image holds every point the camera sees from the nearest depth on, on either
// side
TEST(DepthSensorTest, ProjectorSeesWhatTheCameraSees) {
  const CameraModel camera = CameraLookingDown(640, 480);
  for (const double baseline : {120.0, -120.0}) {
    const CameraModel projector = ProjectorCamera(camera, baseline, 300);
    EXPECT_EQ(projector.width, camera.width);
    const Eigen::Vector3d offset =
        camera.world_from_camera.inverse() * projector.world_from_camera.translation();
    EXPECT_NEAR((offset - Eigen::Vector3d(baseline, 0, 0)).norm(), 0, 1e-9);
    for (const double z : {300.0, 450.0, 5000.0}) {
      for (const double u : {0.0, 639.0}) {
        for (const double v : {0.0, 479.0}) {
          const double x = (u - camera.cx) * z / camera.fx - baseline;
          const double y = (v - camera.cy) * z / camera.fy;
          const double pu = projector.fx * x / z + projector.cx;
          const double pv = projector.fy * y / z + projector.cy;
          EXPECT_GE(pu, 0);
          EXPECT_LT(pu + 1, projector.width);
          EXPECT_GE(pv, 0);
          EXPECT_LT(pv + 1, projector.height);
        }
      }
    }
  }
  EXPECT_THROW(ProjectorCamera(camera, 0, 300), std::invalid_argument);
}

}  // namespace
}  // namespace stackgen
