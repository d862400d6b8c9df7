#include "gen/annotate/pose.h"

#include <cmath>
#include <random>
#include <stdexcept>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

Eigen::Matrix3d Rz(double deg) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}
Eigen::Matrix3d Ry(double deg) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
}
Eigen::Matrix3d Rx(double deg) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
}

// a rotation drawn uniformly from a fixed-seed engine (normalised Gaussian quaternion)
Eigen::Matrix3d RandomRotation(std::mt19937_64& engine) {
  std::normal_distribution<double> normal;
  Eigen::Quaterniond q(normal(engine), normal(engine), normal(engine), normal(engine));
  return q.normalized().toRotationMatrix();
}

Eigen::Isometry3d MakeIsometry(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t) {
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.linear() = rotation;
  transform.translation() = t;
  return transform;
}

// Rz(30) * Ry(20) * Rx(10) reads back as (alpha, beta, gamma) = (30, 20, 10).
TEST(PoseTest, KnownPostureAngles) {
  const Eigen::Vector3d angles = PostureAnglesDeg(Rz(30) * Ry(20) * Rx(10));
  EXPECT_NEAR(angles[0], 30.0, 1e-12);
  EXPECT_NEAR(angles[1], 20.0, 1e-12);
  EXPECT_NEAR(angles[2], 10.0, 1e-12);
  EXPECT_TRUE(RotationFromPostureDeg({30, 20, 10}).isApprox(Rz(30) * Ry(20) * Rx(10), 1e-14));
  // negative angles and the open end of the range: -180 is reported as 180
  const Eigen::Vector3d other = PostureAnglesDeg(Rz(-120) * Ry(-45) * Rx(180));
  EXPECT_NEAR(other[0], -120.0, 1e-12);
  EXPECT_NEAR(other[1], -45.0, 1e-12);
  EXPECT_NEAR(std::abs(other[2]), 180.0, 1e-12);
  EXPECT_NEAR(PostureAnglesDeg(Rz(180))[0], 180.0, 1e-12);
  EXPECT_EQ(PostureAnglesDeg(Eigen::Matrix3d::Identity()), Eigen::Vector3d::Zero());
}

// 1,000 random rotations survive rotation -> angles -> rotation, angles stay in range.
TEST(PoseTest, RandomRoundTrip) {
  std::mt19937_64 engine(42);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Matrix3d rotation = RandomRotation(engine);
    const Eigen::Vector3d angles = PostureAnglesDeg(rotation);
    EXPECT_GT(angles[0], -180.0);
    EXPECT_LE(angles[0], 180.0);
    EXPECT_GE(angles[1], -90.0);
    EXPECT_LE(angles[1], 90.0);
    EXPECT_GT(angles[2], -180.0);
    EXPECT_LE(angles[2], 180.0);
    const Eigen::Matrix3d back = RotationFromPostureDeg(angles);
    ASSERT_LT((back - rotation).cwiseAbs().maxCoeff(), 1e-9) << "rotation " << i;
    // the angles themselves round-trip too (away from gimbal lock)
    const Eigen::Vector3d again = PostureAnglesDeg(back);
    EXPECT_LT((again - angles).cwiseAbs().maxCoeff(), 1e-9) << "rotation " << i;
  }
}

// At beta = +-90 all of the rotation about the vertical goes into alpha and gamma is 0.
TEST(PoseTest, GimbalLock) {
  // Rz(50) Ry(90) Rx(20) = Rz(50 - 20) Ry(90): alpha 30, gamma 0
  const Eigen::Vector3d up = PostureAnglesDeg(Rz(50) * Ry(90) * Rx(20));
  EXPECT_NEAR(up[0], 30.0, 1e-9);
  EXPECT_EQ(up[1], 90.0);
  EXPECT_EQ(up[2], 0.0);
  // Rz(50) Ry(-90) Rx(20) = Rz(50 + 20) Ry(-90): alpha 70, gamma 0
  const Eigen::Vector3d down = PostureAnglesDeg(Rz(50) * Ry(-90) * Rx(20));
  EXPECT_NEAR(down[0], 70.0, 1e-9);
  EXPECT_EQ(down[1], -90.0);
  EXPECT_EQ(down[2], 0.0);
  // both read back as the same rotation
  EXPECT_LT((RotationFromPostureDeg(up) - Rz(50) * Ry(90) * Rx(20)).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((RotationFromPostureDeg(down) - Rz(50) * Ry(-90) * Rx(20)).cwiseAbs().maxCoeff(),
            1e-12);
}

// The message holds the row-major rotation, mm translation and a unit quaternion with w >= 0
// that describes the same rotation.
TEST(PoseTest, MessageFields) {
  std::mt19937_64 engine(7);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Matrix3d rotation = RandomRotation(engine);
    const Eigen::Isometry3d transform = MakeIsometry(rotation, {12.5, -3.0, 400.0});
    const stackgen::pose message = ToPoseMessage(transform);
    EXPECT_EQ(message.translation_mm[0], 12.5);
    EXPECT_EQ(message.translation_mm[1], -3.0);
    EXPECT_EQ(message.translation_mm[2], 400.0);
    EXPECT_EQ(message.rotation[1], rotation(0, 1));  // row-major: r01 second
    EXPECT_EQ(message.rotation[3], rotation(1, 0));
    const Eigen::Quaterniond q(message.quaternion_wxyz[0], message.quaternion_wxyz[1],
                               message.quaternion_wxyz[2], message.quaternion_wxyz[3]);
    EXPECT_GE(q.w(), 0.0);
    EXPECT_NEAR(q.norm(), 1.0, 1e-12);
    EXPECT_LT((q.toRotationMatrix() - rotation).cwiseAbs().maxCoeff(), 1e-12);
    // and back
    const Eigen::Isometry3d back = FromPoseMessage(message);
    EXPECT_TRUE(back.isApprox(transform, 1e-15));
  }
  // a half turn has w = 0: the first nonzero component is made positive
  const stackgen::pose half = ToPoseMessage(MakeIsometry(Rx(180), Eigen::Vector3d::Zero()));
  EXPECT_NEAR(half.quaternion_wxyz[0], 0.0, 1e-15);
  EXPECT_NEAR(half.quaternion_wxyz[1], 1.0, 1e-15);
}

// A message whose rotation is not a rotation, or holds NaN, is refused naming the field.
TEST(PoseTest, BadMessageThrows) {
  stackgen::pose message = ToPoseMessage(Eigen::Isometry3d::Identity());
  message.rotation[0] = 2.0;
  EXPECT_THROW(FromPoseMessage(message), std::runtime_error);
  message = ToPoseMessage(Eigen::Isometry3d::Identity());
  message.rotation[8] = -1.0;  // a reflection
  EXPECT_THROW(FromPoseMessage(message), std::runtime_error);
  message = ToPoseMessage(Eigen::Isometry3d::Identity());
  message.translation_mm[2] = NAN;
  try {
    FromPoseMessage(message);
    FAIL() << "no throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("translation_mm[2]"), std::string::npos) << e.what();
  }
}

// Camera and world frames agree: camera_from_object = inverse(world_from_camera) *
// world_from_object, and a point of the object lands at the same place either way.
TEST(PoseTest, CameraAndWorldFramesConsistent) {
  // a camera 500 mm above the bin floor looking straight down (z forward = world -z)
  const Eigen::Isometry3d world_from_camera =
      MakeIsometry(Rx(180), Eigen::Vector3d(0.0, 0.0, 500.0));
  const Eigen::Isometry3d world_from_object =
      MakeIsometry(Rz(30) * Ry(20) * Rx(10), Eigen::Vector3d(10.0, 20.0, 5.0));
  const Eigen::Isometry3d camera_from_object = world_from_camera.inverse() * world_from_object;
  const stackgen::pose message = ToPoseMessage(camera_from_object);
  // the object origin is 495 mm in front of the camera, x to the right, y flipped
  EXPECT_NEAR(message.translation_mm[0], 10.0, 1e-12);
  EXPECT_NEAR(message.translation_mm[1], -20.0, 1e-12);
  EXPECT_NEAR(message.translation_mm[2], 495.0, 1e-12);
  // any object point maps the same way through both chains
  const Eigen::Vector3d point_in_object(3.0, -4.0, 7.0);
  const Eigen::Vector3d via_world =
      world_from_camera.inverse() * (world_from_object * point_in_object);
  const Eigen::Vector3d via_camera = FromPoseMessage(message) * point_in_object;
  EXPECT_LT((via_world - via_camera).norm(), 1e-12);
}

}  // namespace
}  // namespace stackgen
