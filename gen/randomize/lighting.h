#pragma once

#include <random>
#include <vector>

#include "gen/render/lights.h"
#include "stackgen_config.pb.h"

namespace stackgen {

/// Draws the lights of one scene after the paper: count_min..count_max lights, each a point light
/// (chance point_fraction) or a directional one, from a direction up to max_tilt_deg off straight
/// above the bin floor centre (azimuth uniform), a point light distance_min_mm..distance_max_mm
/// away from the floor centre; ambient, diffuse and specular terms each uniform in their range and
/// divided by the number of lights. With randomize false: one directional light straight down
/// with the middle of each range. Always takes the same number of values from `engine`, so the
/// settings do not shift later draws.
std::vector<Light> SampleLights(const config::LightingConfig& config, std::mt19937_64& engine);

/// Draws the material gains of one part type for one scene: a value gain in
/// [value_gain_min, value_gain_max] times a per-channel tint 1 +- tint_max, and highlight and
/// shininess gains in their ranges (shininess log-uniform), then a roughness gain in
/// [roughness_gain_min, roughness_gain_max] and a metallic shift in +-metallic_jitter. With
/// randomize false: no change. Always takes the same number of values (eight) from `engine`.
MaterialGain SampleMaterialGain(const config::AppearanceConfig& config, std::mt19937_64& engine);

}  // namespace stackgen
