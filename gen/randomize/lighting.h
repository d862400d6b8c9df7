#pragma once

#include <optional>
#include <random>
#include <vector>

#include <Eigen/Core>

#include "gen/render/lights.h"
#include "stackgen_config.pb.h"

namespace stackgen {

/// Draws the lights of one scene after the paper: count_min..count_max lights, each a point light
/// (chance point_fraction) or a directional one, from a direction up to max_tilt_deg off straight
/// above the bin floor centre (azimuth uniform), a point light distance_min_mm..distance_max_mm
/// away from the floor centre; ambient, diffuse and specular terms each uniform in their range and
/// divided by the number of lights; with color_temperature_min_k/max_k set, each light's colour
/// a black body's of a temperature drawn in that range (else white). With randomize false: one
/// white directional light straight down with the middle of each range. Always takes the same
/// number of values from `engine` (1 + 3 x 7, then 3 temperatures), so the settings do not shift
/// later draws.
std::vector<Light> SampleLights(const config::LightingConfig& config, std::mt19937_64& engine);

/// The colour of a black body at `kelvin` (1667..25000, clamped), as linear sRGB of luminance 1:
/// the Planckian locus' chromaticity after Kim et al. (2002), to XYZ at Y = 1, to linear sRGB
/// (D65), negative channels clipped, scaled back to luminance 1. 3000 K is orange, 6500 K about
/// white, 10000 K blue.
Eigen::Vector3f BlackBodyColor(double kelvin);

/// Draws whether a scene has a ring light around the lens (chance camera_light_probability, and
/// randomize true), its strength, uniform in [diffuse_min, diffuse_max], and its colour
/// temperature as SampleLights draws one: a point light at `camera_position` (mm, world frame)
/// with no ambient or specular term, or none. Always takes three values from `engine`; called
/// after SampleLights on the same engine, it leaves that function's draws as they were.
std::optional<Light> SampleCameraLight(const config::LightingConfig& config,
                                       const Eigen::Vector3d& camera_position,
                                       std::mt19937_64& engine);

/// Draws each light's angular radius (Light::radius_rad), uniform in [light_radius_deg_min,
/// light_radius_deg_max] degrees; with randomize false, the middle of that range. Always takes
/// three values from `engine` whatever the settings and the number of lights; draw it from an
/// engine of its own, so that no other draw moves.
void DrawLightRadii(const config::LightingConfig& config, std::mt19937_64& engine,
                    std::vector<Light>* lights);

/// Draws the material gains of one part type for one scene: a value gain in
/// [value_gain_min, value_gain_max] times a per-channel tint 1 +- tint_max, and highlight and
/// shininess gains in their ranges (shininess log-uniform), then a roughness gain in
/// [roughness_gain_min, roughness_gain_max] and a metallic shift in +-metallic_jitter. With
/// randomize false: no change. Always takes the same number of values (eight) from `engine`.
MaterialGain SampleMaterialGain(const config::AppearanceConfig& config, std::mt19937_64& engine);

}  // namespace stackgen
