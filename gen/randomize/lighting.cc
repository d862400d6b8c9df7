#include "gen/randomize/lighting.h"

#include <algorithm>
#include <cmath>

#include "gen/randomize/uniform.h"

namespace stackgen {
namespace {

constexpr int kMostLights = 3;  // LightingConfig.count_max is at most 3

}  // namespace

std::vector<Light> SampleLights(const config::LightingConfig& config, std::mt19937_64& engine) {
  // every draw is made whatever the settings: the count, then 7 values per possible light
  const double count_draw = Uniform(engine, 0, 1);
  struct Draw {
    double tilt, azimuth, kind, distance, ambient, diffuse, specular;
  };
  Draw draws[kMostLights];
  for (Draw& d : draws) {
    d.tilt = Uniform(engine, 0, 1);
    d.azimuth = Uniform(engine, 0, 2 * M_PI);
    d.kind = Uniform(engine, 0, 1);
    d.distance = Uniform(engine, config.distance_min_mm(), config.distance_max_mm());
    d.ambient = Uniform(engine, config.ambient_min(), config.ambient_max());
    d.diffuse = Uniform(engine, config.diffuse_min(), config.diffuse_max());
    d.specular = Uniform(engine, config.specular_min(), config.specular_max());
  }

  // fixed lighting: one light straight down, the middle of each range
  if (!config.randomize()) {
    Light light;
    light.type = Light::Type::kDirectional;
    light.direction_world = Eigen::Vector3f(0, 0, -1);
    light.ambient = static_cast<float>((config.ambient_min() + config.ambient_max()) / 2);
    light.diffuse = static_cast<float>((config.diffuse_min() + config.diffuse_max()) / 2);
    light.specular = static_cast<float>((config.specular_min() + config.specular_max()) / 2);
    return {light};
  }

  // count, then each light; the terms are shared out so their total stays in range
  const int span = config.count_max() - config.count_min() + 1;
  const int count = config.count_min() + std::min(span - 1, static_cast<int>(count_draw * span));
  std::vector<Light> lights;
  for (int i = 0; i < count; ++i) {
    const Draw& d = draws[i];
    const double tilt = d.tilt * config.max_tilt_deg() * M_PI / 180;
    // unit vector from the floor centre towards the light
    const Eigen::Vector3d towards(std::sin(tilt) * std::cos(d.azimuth),
                                  std::sin(tilt) * std::sin(d.azimuth), std::cos(tilt));
    Light light;
    if (d.kind < config.point_fraction()) {
      light.type = Light::Type::kPoint;
      light.position_world = (d.distance * towards).cast<float>();
    } else {
      light.type = Light::Type::kDirectional;
      light.direction_world = (-towards).cast<float>();
    }
    light.ambient = static_cast<float>(d.ambient / count);
    light.diffuse = static_cast<float>(d.diffuse / count);
    light.specular = static_cast<float>(d.specular / count);
    lights.push_back(light);
  }
  return lights;
}

MaterialGain SampleMaterialGain(const config::AppearanceConfig& config, std::mt19937_64& engine) {
  // eight draws whatever the settings
  const double value = Uniform(engine, config.value_gain_min(), config.value_gain_max());
  double tint[3];
  for (double& t : tint) t = Uniform(engine, -config.tint_max(), config.tint_max());
  const double specular = Uniform(engine, config.specular_gain_min(), config.specular_gain_max());
  const double log_shininess =
      Uniform(engine, std::log(config.shininess_gain_min()), std::log(config.shininess_gain_max()));
  const double roughness =
      Uniform(engine, config.roughness_gain_min(), config.roughness_gain_max());
  const double metallic = Uniform(engine, -config.metallic_jitter(), config.metallic_jitter());
  MaterialGain gain;
  if (!config.randomize()) return gain;
  gain.roughness = static_cast<float>(roughness);
  gain.metallic = static_cast<float>(metallic);
  for (int c = 0; c < 3; ++c) gain.color[c] = static_cast<float>(value * (1 + tint[c]));
  gain.specular = static_cast<float>(specular);
  gain.shininess = static_cast<float>(std::exp(log_shininess));
  return gain;
}

}  // namespace stackgen
