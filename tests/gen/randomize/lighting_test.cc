// The lights of a scene (gen/randomize/lighting.h): the ring light around the lens, and the draws
// it takes.
#include "gen/randomize/lighting.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

// a ring light sits at the camera, as a point light of a strength in the diffuse range with no
// ambient or specular term, as often as camera_light_probability says; never with randomize
// false; always three draws, after which SampleLights' own draws are untouched
TEST(LightingTest, RingLightAtTheCamera) {
  config::LightingConfig config;
  config.set_camera_light_probability(0.25);
  const Eigen::Vector3d camera(10, -20, 450);
  std::mt19937_64 engine(9);
  int rings = 0;
  for (int scene = 0; scene < 800; ++scene) {
    const auto ring = SampleCameraLight(config, camera, engine);
    if (!ring) continue;
    ++rings;
    ASSERT_EQ(ring->type, Light::Type::kPoint);
    ASSERT_TRUE(ring->position_world.isApprox(camera.cast<float>()));
    ASSERT_GE(ring->diffuse, config.diffuse_min());
    ASSERT_LE(ring->diffuse, config.diffuse_max());
    ASSERT_EQ(ring->ambient, 0.f);
    ASSERT_EQ(ring->specular, 0.f);
  }
  // a quarter of 800, within four standard deviations
  EXPECT_NEAR(rings, 200, 50);

  config::LightingConfig fixed = config;
  fixed.set_randomize(false);
  fixed.set_camera_light_probability(1);
  std::mt19937_64 a(3), reference(3);
  EXPECT_FALSE(SampleCameraLight(fixed, camera, a));
  reference.discard(3);
  EXPECT_EQ(a, reference);

  // the lights drawn before the ring light are the same with or without it
  config::LightingConfig none;
  std::mt19937_64 b(21), c(21);
  const std::vector<Light> with = SampleLights(config, b);
  const std::vector<Light> without = SampleLights(none, c);
  ASSERT_EQ(with.size(), without.size());
  for (size_t i = 0; i < with.size(); ++i) {
    EXPECT_EQ(with[i].diffuse, without[i].diffuse);
    EXPECT_TRUE(with[i].direction_world.isApprox(without[i].direction_world));
  }
}

// a black body is orange at 2700 K, about white at 6500 K and blue at 12000 K, always of
// luminance 1; lights take colours of the configured range, white without one, and the colours
// move none of the draws before them
TEST(LightingTest, LightsOfAColourTemperature) {
  const auto luminance = [](const Eigen::Vector3f& c) {
    return 0.2126f * c.x() + 0.7152f * c.y() + 0.0722f * c.z();
  };
  const Eigen::Vector3f warm = BlackBodyColor(2700), day = BlackBodyColor(6500),
                        cold = BlackBodyColor(12000);
  for (const Eigen::Vector3f& c : {warm, day, cold}) EXPECT_NEAR(luminance(c), 1.f, 1e-5f);
  EXPECT_GT(warm.x(), 1.3f * warm.y());
  EXPECT_LT(warm.z(), 0.6f * warm.y());
  EXPECT_NEAR(day.x(), 1.f, 0.1f);
  EXPECT_NEAR(day.z(), 1.f, 0.15f);
  EXPECT_GT(cold.z(), 1.2f * cold.x());

  config::LightingConfig coloured;
  coloured.set_count_min(3);
  coloured.set_color_temperature_min_k(3000);
  coloured.set_color_temperature_max_k(3500);
  config::LightingConfig white = coloured;
  white.clear_color_temperature_min_k();
  white.clear_color_temperature_max_k();
  std::mt19937_64 a(8), b(8);
  for (int scene = 0; scene < 50; ++scene) {
    const std::vector<Light> lights = SampleLights(coloured, a);
    const std::vector<Light> plain = SampleLights(white, b);
    ASSERT_EQ(lights.size(), 3u);
    for (size_t i = 0; i < lights.size(); ++i) {
      ASSERT_GT(lights[i].color.x(), lights[i].color.z() * 1.5f);
      ASSERT_LT(lights[i].color.x(), BlackBodyColor(3000).x() + 1e-5f);
      ASSERT_GT(lights[i].color.x(), BlackBodyColor(3500).x() - 1e-5f);
      ASSERT_TRUE(plain[i].color.isApprox(Eigen::Vector3f(1, 1, 1)));
      ASSERT_EQ(lights[i].diffuse, plain[i].diffuse);
    }
  }
  EXPECT_EQ(a, b);
}

// each light's size is drawn in its range, three draws whatever the number of lights (so the
// next draw is the same), the middle of the range with randomize false
TEST(LightingTest, LightRadiiInTheirRangeWithAFixedNumberOfDraws) {
  config::LightingConfig config;
  config.set_light_radius_deg_min(2);
  config.set_light_radius_deg_max(20);
  std::mt19937_64 engine(3);
  double smallest = 90, largest = 0;
  for (int scene = 0; scene < 200; ++scene) {
    std::vector<Light> lights(1 + scene % 3);
    std::mt19937_64 copy = engine;
    DrawLightRadii(config, engine, &lights);
    copy.discard(3);
    ASSERT_EQ(engine, copy);
    for (const Light& light : lights) {
      const double degrees = light.radius_rad * 180 / M_PI;
      smallest = std::min(smallest, degrees);
      largest = std::max(largest, degrees);
    }
  }
  EXPECT_GE(smallest, 2 - 1e-4);
  EXPECT_LT(smallest, 3);
  EXPECT_LE(largest, 20 + 1e-4);
  EXPECT_GT(largest, 19);
  config.set_randomize(false);
  std::vector<Light> fixed(2);
  DrawLightRadii(config, engine, &fixed);
  EXPECT_NEAR(fixed[1].radius_rad, 11 * M_PI / 180, 1e-6);
  std::vector<Light> points(3);
  DrawLightRadii(config::LightingConfig(), engine, &points);
  for (const Light& light : points) EXPECT_EQ(light.radius_rad, 0.f);
}

}  // namespace
}  // namespace stackgen
