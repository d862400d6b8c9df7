#pragma once

// The plain settings of a scene's lights and of the per-draw material gains: what randomisation
// draws (gen/randomize/lighting.h) and the renderer takes, without the renderer's EGL/GL.

#include <Eigen/Core>

namespace stackgen {

/// Per-draw randomisation applied on top of whichever material a surface uses.
struct MaterialGain {
  /// Multiplies the colour (display values); the result is clamped to [0, 1].
  Eigen::Vector3f color{1, 1, 1};
  float specular = 1.f;   // multiplies the highlight strength
  float shininess = 1.f;  // multiplies the exponent
  float roughness = 1.f;  // physically based: multiplies the roughness (result clamped to 0..1)
  float metallic = 0.f;   // physically based: added to metallic (result clamped to 0..1)
};

/// A light with the paper's three OpenGL terms (ambient, diffuse, specular). Ambient terms of all
/// lights add up; no light falls off with distance. Physically based shading uses `diffuse` as
/// the light's strength (a white matte surface facing it shows `diffuse` in linear light: an
/// irradiance of pi x diffuse) and ignores ambient and specular: the environment is the ambient
/// light, and highlights follow from the material.
struct Light {
  enum class Type { kDirectional, kPoint };
  Type type = Type::kDirectional;
  Eigen::Vector3f direction_world{0, 0, -1};   // directional: direction the light travels, unit
  Eigen::Vector3f position_world{0, 0, 1000};  // point light: position, mm, world frame
  float ambient = 0.25f, diffuse = 0.7f, specular = 0.4f;
  /// Physically based shading: the light's colour, linear RGB of luminance 1 (white: 1, 1, 1),
  /// multiplying its strength per channel. Blinn-Phong ignores it.
  Eigen::Vector3f color{1, 1, 1};
  /// Physically based shading with shadows: the lamp's angular radius seen from the scene,
  /// radians, 0..kMaxLightRadiusRad. 0: a point, hard shadows. Larger: a lamp of that size, whose
  /// shadows soften with the distance between what casts them and what they fall on (a shadow
  /// edge 2 d tan(radius) wide at a distance d). Blinn-Phong ignores it.
  float radius_rad = 0.f;
};

/// Largest Light::radius_rad, radians (45 degrees).
inline constexpr float kMaxLightRadiusRad = 0.7853982f;

}  // namespace stackgen
