#pragma once

// Test helpers: cameras of known geometry.

#include <Eigen/Geometry>

#include "gen/render/renderer.h"

namespace stackgen {
namespace testing {

/// A camera at world (0, 0, height_mm) looking straight down at the z = 0 plane, image x along
/// world x and y along -y; width x height pixels, fx = fy = 400, the principal point at the
/// image's centre.
inline CameraModel CameraLookingDown(double height_mm, int width = 320, int height = 240) {
  CameraModel camera;
  camera.width = width;
  camera.height = height;
  camera.fx = camera.fy = 400;
  camera.cx = (width - 1) / 2.0;
  camera.cy = (height - 1) / 2.0;
  camera.world_from_camera = Eigen::Translation3d(0, 0, height_mm) * Eigen::Isometry3d::Identity();
  camera.world_from_camera.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  return camera;
}

}  // namespace testing
}  // namespace stackgen
