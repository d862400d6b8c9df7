#pragma once

// Test helper: environments made in code for the renderer's tests.

#include <opencv2/core.hpp>

#include "gen/render/environment.h"

namespace stackgen {
namespace testing {

/// A height x 2 height environment whose radiance is radiance_of(direction) (an
/// Eigen::Vector3f of an Eigen::Vector3d) at each pixel centre.
template <typename F>
EnvironmentMap EnvironmentOf(F radiance_of, int height = 64) {
  EnvironmentMap map;
  map.name = "test";
  map.radiance.create(height, 2 * height, CV_32FC3);
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < 2 * height; ++u) {
      const Eigen::Vector3f c = radiance_of(DirectionOfPixel(u, v, 2 * height, height));
      map.radiance.at<cv::Vec3f>(v, u) = cv::Vec3f(c.x(), c.y(), c.z());
    }
  }
  return map;
}

}  // namespace testing
}  // namespace stackgen
