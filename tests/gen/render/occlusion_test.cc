// gen/render/occlusion.cc: how much sky the depth image leaves open over a floor, at the foot of
// a block and in a crack.
#include "gen/render/occlusion.h"

#include <cmath>
#include <functional>
#include <stdexcept>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "tests/support/cameras.h"

namespace stackgen {
namespace {

// 320 x 240, fx = fy = 400, straight down from 300 mm over a floor at camera z 300
Intrinsics Camera() { return testing::CameraLookingDown(300); }

// the depth image of a floor at z 300 with blocks on it: `top(x, y)` is the camera z of a
// block's top over floor point (x, y) mm, or 0 where there is none (a block's top at z is seen
// where the pixel's ray meets it; its sides face away from a camera straight above)
cv::Mat DepthOf(const std::function<double(double, double)>& top) {
  const Intrinsics camera = Camera();
  cv::Mat depth(camera.height, camera.width, CV_32FC1);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const double x = (u - camera.cx) / camera.fx;
      const double y = (v - camera.cy) / camera.fy;
      double z = 300;
      // the nearest block top the ray meets
      for (double zt = 200; zt < 300; zt += 1) {
        const double t = top(x * zt, y * zt);
        if (t > 0 && std::abs(t - zt) < 0.5) {
          z = t;
          break;
        }
      }
      depth.at<float>(v, u) = static_cast<float>(z);
    }
  }
  return depth;
}

// the pixel that sees floor point (x, y) mm
cv::Point PixelOf(double x_mm, double y_mm) {
  const Intrinsics camera = Camera();
  return {static_cast<int>(std::lround(camera.cx + camera.fx * x_mm / 300)),
          static_cast<int>(std::lround(camera.cy + camera.fy * y_mm / 300))};
}

cv::Mat VisibilityOf(const cv::Mat& depth, double radius_mm = 150) {
  cv::Mat visibility;
  EnvironmentVisibility(depth, Camera(), radius_mm, &visibility);
  return visibility;
}

// an open floor, and what nothing covers, keep the whole sky
TEST(OcclusionTest, OpenFloorKeepsTheSky) {
  cv::Mat depth = DepthOf([](double, double) { return 0.0; });
  depth(cv::Rect(0, 0, 40, 240)) = 0.f;
  const cv::Mat visibility = VisibilityOf(depth);
  ASSERT_EQ(visibility.type(), CV_32FC1);
  double lowest = 0, highest = 0;
  cv::minMaxLoc(visibility, &lowest, &highest);
  EXPECT_GE(lowest, 0.99);
  EXPECT_LE(highest, 1.0);
}

// beside a block 60 mm tall the floor loses part of its sky, the more the nearer; on its top,
// none; a smaller radius reaches less far (the picture spans x -120..120 mm, y -90..90 on the
// floor)
TEST(OcclusionTest, FloorBesideABlockLosesSky) {
  const cv::Mat depth = DepthOf([](double x, double y) {
    return std::abs(x) < 30 && std::abs(y) < 30 ? 240.0 : 0.0;
  });
  const cv::Mat visibility = VisibilityOf(depth, 100);
  const auto at = [](const cv::Mat& image, double x, double y) {
    const cv::Point p = PixelOf(x, y);
    return image.at<float>(p.y, p.x);
  };
  // the floor first seen past the block's top edge lies at 37.5 mm
  const float foot = at(visibility, 40, 0);
  EXPECT_GT(foot, 0.5f);
  EXPECT_LT(foot, 0.85f);
  EXPECT_LT(foot, at(visibility, 70, 0));
  EXPECT_LT(at(visibility, 70, 0), 0.99f);
  EXPECT_GE(at(visibility, 0, 0), 0.99f);
  const cv::Mat near = VisibilityOf(depth, 40);
  EXPECT_GT(at(near, 40, 0), foot);
  EXPECT_GE(at(near, 110, 0), 0.99f);
  EXPECT_GE(at(near, 0, 0), 0.99f);
}

// the floor of a crack 10 mm wide between blocks 80 mm tall sees little sky, less than beside
// one block
TEST(OcclusionTest, CrackFloorSeesLittleSky) {
  // seen from above: the walls' tops at z 220, their inner faces (x = +-5) down to the floor
  const Intrinsics camera = Camera();
  cv::Mat depth(camera.height, camera.width, CV_32FC1);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const double slope = std::abs(u - camera.cx) / camera.fx;
      depth.at<float>(v, u) =
          static_cast<float>(slope * 220 >= 5 ? 220 : (slope * 300 >= 5 ? 5 / slope : 300));
    }
  }
  const cv::Mat visibility = VisibilityOf(depth);
  const cv::Point crack = PixelOf(0, 0);
  ASSERT_EQ(depth.at<float>(crack.y, crack.x), 300.f);
  EXPECT_LT(visibility.at<float>(crack.y, crack.x), 0.45f);
  // the walls' tops keep their sky
  const cv::Point wall = PixelOf(60 * 300 / 220.0, 0);
  EXPECT_GE(visibility.at<float>(wall.y, wall.x), 0.99f);
}

TEST(OcclusionTest, BadInputThrows) {
  cv::Mat visibility;
  EXPECT_THROW(EnvironmentVisibility(cv::Mat(240, 320, CV_64FC1), Camera(), 100, &visibility),
               std::invalid_argument);
  EXPECT_THROW(EnvironmentVisibility(cv::Mat(120, 320, CV_32FC1), Camera(), 100, &visibility),
               std::invalid_argument);
  EXPECT_THROW(EnvironmentVisibility(cv::Mat(240, 320, CV_32FC1, cv::Scalar(300)), Camera(), 0,
                                     &visibility),
               std::invalid_argument);
}

}  // namespace
}  // namespace stackgen
