#include "gen/randomize/lighting.h"

#include <algorithm>
#include <cmath>

#include "gen/randomize/uniform.h"

namespace stackgen {
namespace {

constexpr int kMostLights = 3;  // LightingConfig.count_max is at most 3

// a light's colour for a draw in [0, 1): white, or a black body's in the configured range
Eigen::Vector3f ColorOfDraw(const config::LightingConfig& config, double unit) {
  if (config.color_temperature_min_k() <= 0 && config.color_temperature_max_k() <= 0) {
    return Eigen::Vector3f(1, 1, 1);
  }
  return BlackBodyColor(config.color_temperature_min_k() +
                        unit * (config.color_temperature_max_k() - config.color_temperature_min_k()));
}

}  // namespace

Eigen::Vector3f BlackBodyColor(double kelvin) {
  const double t = std::clamp(kelvin, 1667.0, 25000.0);
  // the Planckian locus in CIE 1931 xy, Kim et al. (2002): cubic splines in 1/T and in x
  const double t1 = 1e3 / t, t2 = t1 * t1, t3 = t2 * t1;
  const double x = t <= 4000 ? -0.2661239 * t3 - 0.2343589 * t2 + 0.8776956 * t1 + 0.179910
                             : -3.0258469 * t3 + 2.1070379 * t2 + 0.2226347 * t1 + 0.240390;
  const double y = t <= 2222   ? -1.1063814 * x * x * x - 1.34811020 * x * x + 2.18555832 * x -
                                   0.20219683
                   : t <= 4000 ? -0.9549476 * x * x * x - 1.37418593 * x * x + 2.09137015 * x -
                                     0.16748867
                               : 3.0817580 * x * x * x - 5.87338670 * x * x + 3.75112997 * x -
                                     0.37001483;
  // XYZ at Y = 1, then linear sRGB (IEC 61966-2-1)
  const Eigen::Vector3d xyz(x / y, 1.0, (1 - x - y) / y);
  Eigen::Matrix3d rgb_from_xyz;
  rgb_from_xyz << 3.2406, -1.5372, -0.4986, -0.9689, 1.8758, 0.0415, 0.0557, -0.2040, 1.0570;
  const Eigen::Vector3d rgb = (rgb_from_xyz * xyz).cwiseMax(0.0);
  const double luminance = 0.2126 * rgb.x() + 0.7152 * rgb.y() + 0.0722 * rgb.z();
  return (rgb / luminance).cast<float>();
}

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
  // (after the draws above, so that a light's colour moves none of them)
  double temperatures[kMostLights];
  for (double& t : temperatures) t = Uniform(engine, 0, 1);

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
    light.color = ColorOfDraw(config, temperatures[i]);
    lights.push_back(light);
  }
  return lights;
}

std::optional<Light> SampleCameraLight(const config::LightingConfig& config,
                                       const Eigen::Vector3d& camera_position,
                                       std::mt19937_64& engine) {
  const double chance = Uniform(engine, 0, 1);
  const double strength = Uniform(engine, config.diffuse_min(), config.diffuse_max());
  const double temperature = Uniform(engine, 0, 1);
  if (!config.randomize() || !(chance < config.camera_light_probability())) return std::nullopt;
  Light ring;
  ring.type = Light::Type::kPoint;
  ring.position_world = camera_position.cast<float>();
  ring.ambient = 0;
  ring.diffuse = static_cast<float>(strength);
  ring.specular = 0;
  ring.color = ColorOfDraw(config, temperature);
  return ring;
}

void DrawLightRadii(const config::LightingConfig& config, std::mt19937_64& engine,
                    std::vector<Light>* lights) {
  constexpr int kDraws = kMostLights;
  double draws[kDraws];
  for (double& d : draws) {
    d = Uniform(engine, config.light_radius_deg_min(), config.light_radius_deg_max());
  }
  const double middle = (config.light_radius_deg_min() + config.light_radius_deg_max()) / 2;
  for (size_t i = 0; i < lights->size(); ++i) {
    const double degrees = !config.randomize() ? middle : draws[std::min<size_t>(i, kDraws - 1)];
    (*lights)[i].radius_rad = static_cast<float>(degrees * M_PI / 180);
  }
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
