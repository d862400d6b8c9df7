#include "gen/randomize/camera_pose.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDegPerRad = 180 / kPi;

config::CameraConfig Camera(double distance_jitter_mm, double tilt_max_deg, double roll_max_deg) {
  config::CameraConfig camera;
  camera.set_height_mm(450);
  camera.set_distance_jitter_mm(distance_jitter_mm);
  camera.set_tilt_max_deg(tilt_max_deg);
  camera.set_roll_max_deg(roll_max_deg);
  return camera;
}

// the angle of the optical axis (camera z) from straight down, degrees.
double TiltDeg(const Eigen::Isometry3d& world_from_camera) {
  const double down = -world_from_camera.linear().col(2).z();
  return std::acos(std::clamp(down, -1.0, 1.0)) * kDegPerRad;
}

// the distance of the floor centre from the optical axis ray, mm (infinite when behind).
double FloorCentreOffRay(const Eigen::Isometry3d& world_from_camera) {
  const Eigen::Vector3d to_centre = -world_from_camera.translation();
  const Eigen::Vector3d axis = world_from_camera.linear().col(2);
  if (to_centre.dot(axis) <= 0) return INFINITY;
  return (to_centre - to_centre.dot(axis) * axis).norm();
}

// the rotation left after undoing the tilt along the great circle from the camera centre to the
// top of the sphere, relative to the nominal pose: a turn about the optical axis when the pose
// is tilt-then-roll. Returns its angle, degrees, and sets *off_axis to how far it is from a
// pure z rotation.
double RollDeg(const Eigen::Isometry3d& world_from_camera, double* off_axis) {
  const Eigen::Vector3d centre = world_from_camera.translation();
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  Eigen::Matrix3d untilt = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d axis = centre.normalized().cross(up);
  if (axis.norm() > 1e-12) {
    const double angle = std::acos(std::clamp(centre.normalized().dot(up), -1.0, 1.0));
    untilt = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  }
  const Eigen::Matrix3d nominal = NominalWorldFromCamera(1).linear();
  const Eigen::Matrix3d roll = nominal.transpose() * untilt * world_from_camera.linear();
  *off_axis = std::abs(roll(2, 2) - 1) + roll.col(2).head<2>().norm();
  return std::atan2(roll(1, 0), roll(0, 0)) * kDegPerRad;
}

// the nominal pose looks straight down from the given distance, image x along world x and image
// y along world -y, so a floor point right of and above the centre projects right of and above
// the principal point.
TEST(CameraPoseTest, NominalPoseLooksDown) {
  const Eigen::Isometry3d pose = NominalWorldFromCamera(450);
  Eigen::Matrix4d expected;
  expected << 1, 0, 0, 0,  //
      0, -1, 0, 0,         //
      0, 0, -1, 450,       //
      0, 0, 0, 1;
  EXPECT_EQ(pose.matrix(), expected);
  const Eigen::Vector3d point = pose.inverse() * Eigen::Vector3d(10, 20, 0);
  const Intrinsics intrinsics;
  EXPECT_NEAR(intrinsics.fx * point.x() / point.z() + intrinsics.cx, 319.5 + 800 * 10 / 450.0,
              1e-9);
  EXPECT_NEAR(intrinsics.fy * point.y() / point.z() + intrinsics.cy, 239.5 - 800 * 20 / 450.0,
              1e-9);
}

// with all ranges zero every draw is the nominal pose exactly, and still takes four values.
TEST(CameraPoseTest, ZeroRangesGiveTheNominalPoseExactly) {
  std::mt19937_64 engine(11);
  std::mt19937_64 reference(11);
  for (int i = 0; i < 100; ++i) {
    EXPECT_EQ(SampleWorldFromCamera(Camera(0, 0, 0), engine).matrix(),
              NominalWorldFromCamera(450).matrix());
    reference.discard(4);
    ASSERT_EQ(engine, reference);
  }
}

// over 1000 draws: the distance stays in height +- jitter, the optical axis passes through the
// floor centre, the tilt stays under its maximum, the rest of the rotation is a roll about the
// optical axis within range, and all four spread over their whole ranges.
TEST(CameraPoseTest, DrawsStayInRangesAndSpread) {
  const config::CameraConfig camera = Camera(30, 20, 40);
  std::mt19937_64 engine(2024);
  double distance_min = INFINITY, distance_max = -INFINITY;
  double tilt_min = INFINITY, tilt_max = -INFINITY;
  double roll_min = INFINITY, roll_max = -INFINITY;
  int quadrants[4] = {0, 0, 0, 0};
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Isometry3d pose = SampleWorldFromCamera(camera, engine);
    ASSERT_NEAR((pose.linear().transpose() * pose.linear() - Eigen::Matrix3d::Identity()).norm(), 0,
                1e-12);
    ASSERT_NEAR(pose.linear().determinant(), 1, 1e-12);
    const double distance = pose.translation().norm();
    ASSERT_GE(distance, 420 - 1e-9);
    ASSERT_LE(distance, 480 + 1e-9);
    ASSERT_LT(FloorCentreOffRay(pose), 1e-6);
    const double tilt = TiltDeg(pose);
    ASSERT_LE(tilt, 20 + 1e-9);
    double off_axis = 0;
    const double roll = RollDeg(pose, &off_axis);
    ASSERT_LT(off_axis, 1e-9);
    ASSERT_LE(std::abs(roll), 40 + 1e-9);
    distance_min = std::min(distance_min, distance);
    distance_max = std::max(distance_max, distance);
    tilt_min = std::min(tilt_min, tilt);
    tilt_max = std::max(tilt_max, tilt);
    roll_min = std::min(roll_min, roll);
    roll_max = std::max(roll_max, roll);
    const Eigen::Vector3d centre = pose.translation();
    if (tilt > 1) ++quadrants[(centre.x() < 0) + 2 * (centre.y() < 0)];
  }
  EXPECT_LT(distance_min, 421.2);
  EXPECT_GT(distance_max, 478.8);
  EXPECT_LT(tilt_min, 0.4);
  EXPECT_GT(tilt_max, 19.6);
  EXPECT_LT(roll_min, -39.2);
  EXPECT_GT(roll_max, 39.2);
  for (const int count : quadrants) EXPECT_GT(count, 150);
}

// with no tilt, the roll is the angle of the camera x axis from world x (clockwise seen from
// above, as the image turns), within +-roll_max and spread over the range.
TEST(CameraPoseTest, RollWithoutTiltTurnsTheImageAxes) {
  std::mt19937_64 engine(5);
  double lo = INFINITY, hi = -INFINITY;
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Isometry3d pose = SampleWorldFromCamera(Camera(0, 0, 25), engine);
    const Eigen::Vector3d x_axis = pose.linear().col(0);
    ASSERT_NEAR(x_axis.z(), 0, 1e-15);
    ASSERT_EQ(pose.translation(), Eigen::Vector3d(0, 0, 450));
    const double roll = std::atan2(-x_axis.y(), x_axis.x()) * kDegPerRad;
    ASSERT_LE(std::abs(roll), 25 + 1e-9);
    lo = std::min(lo, roll);
    hi = std::max(hi, roll);
  }
  EXPECT_LT(lo, -24.5);
  EXPECT_GT(hi, 24.5);
}

// the default set-up sees the whole bin; too close, shifted sideways, or with the bin behind it,
// it does not.
TEST(CameraPoseTest, BinInViewChecksEveryCorner) {
  const Intrinsics intrinsics;
  const config::BinConfig bin;
  EXPECT_TRUE(BinInView(intrinsics, NominalWorldFromCamera(450), bin));
  EXPECT_FALSE(BinInView(intrinsics, NominalWorldFromCamera(250), bin));
  Eigen::Isometry3d shifted = NominalWorldFromCamera(450);
  shifted.translation().x() += 60;
  EXPECT_FALSE(BinInView(intrinsics, shifted, bin));
  // below the floor, looking down: every corner is behind the camera, though their pinhole
  // projections land inside the image.
  EXPECT_FALSE(BinInView(intrinsics, NominalWorldFromCamera(-450), bin));
}

// with require_bin_in_view, SampleCameraPose returns only poses that see the bin, though about
// half of the raw draws of this set-up do not; without it, it is the raw draw.
TEST(CameraPoseTest, RequireBinInViewRedraws) {
  const Intrinsics intrinsics;
  const config::BinConfig bin;
  config::CameraConfig camera = Camera(100, 20, 30);
  std::mt19937_64 raw(77);
  int raw_out_of_view = 0;
  for (int i = 0; i < 1000; ++i) {
    raw_out_of_view += !BinInView(intrinsics, SampleWorldFromCamera(camera, raw), bin);
  }
  EXPECT_GT(raw_out_of_view, 300);
  std::mt19937_64 engine(77);
  for (int i = 0; i < 1000; ++i) {
    ASSERT_TRUE(BinInView(intrinsics, SampleCameraPose(camera, intrinsics, bin, engine), bin));
  }
  camera.set_require_bin_in_view(false);
  std::mt19937_64 a(3);
  std::mt19937_64 b(3);
  for (int i = 0; i < 100; ++i) {
    ASSERT_EQ(SampleCameraPose(camera, intrinsics, bin, a).matrix(),
              SampleWorldFromCamera(camera, b).matrix());
  }
}

// the message of the error SampleCameraPose throws, or "" when it returns.
std::string ErrorOf(const config::CameraConfig& camera, const Intrinsics& intrinsics) {
  std::mt19937_64 engine(1);
  try {
    SampleCameraPose(camera, intrinsics, config::BinConfig(), engine);
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "";
}

// a bin that fits the nominal image with 0.0002 px to spare leaves the image at any roll above
// about 3e-5 degrees, so a roll range of +-90 never finds a pose (chance ~3e-7 per draw): it
// throws naming the ranges with their values and the one to lower; a camera too close throws
// naming camera.height_mm.
TEST(CameraPoseTest, ImpossibleSetUpsThrowClearly) {
  Intrinsics tight;
  tight.fx = tight.fy = 1117.666;  // the rim's image spans rows 0.0001..478.9999
  ASSERT_TRUE(BinInView(tight, NominalWorldFromCamera(450), config::BinConfig()));
  const std::string error = ErrorOf(Camera(0, 0, 90), tight);
  EXPECT_NE(error.find("camera.distance_jitter_mm = 0"), std::string::npos) << error;
  EXPECT_NE(error.find("camera.tilt_max_deg = 0"), std::string::npos) << error;
  EXPECT_NE(error.find("camera.roll_max_deg = 90"), std::string::npos) << error;
  EXPECT_NE(error.find("lower camera.roll_max_deg"), std::string::npos) << error;
  EXPECT_EQ(error.find("lower camera.tilt"), std::string::npos) << error;

  config::CameraConfig close = Camera(0, 0, 0);
  close.set_height_mm(200);
  const std::string too_close = ErrorOf(close, Intrinsics());
  EXPECT_NE(too_close.find("camera.height_mm = 200"), std::string::npos) << too_close;

  // the same set-ups without the requirement return a pose.
  close.set_require_bin_in_view(false);
  EXPECT_EQ(ErrorOf(close, Intrinsics()), "");
}

// the same seed gives the same pose; switching tilt or roll on leaves the drawn distance, and the
// number of values taken, unchanged.
TEST(CameraPoseTest, DeterministicAndIndependentDraws) {
  std::mt19937_64 a(99);
  std::mt19937_64 b(99);
  EXPECT_EQ(SampleWorldFromCamera(Camera(30, 5, 10), a).matrix(),
            SampleWorldFromCamera(Camera(30, 5, 10), b).matrix());

  std::mt19937_64 plain(123);
  std::mt19937_64 tilted(123);
  std::mt19937_64 rolled(123);
  for (int i = 0; i < 100; ++i) {
    const double distance = SampleWorldFromCamera(Camera(30, 0, 0), plain).translation().norm();
    const Eigen::Isometry3d with_tilt = SampleWorldFromCamera(Camera(30, 40, 0), tilted);
    const Eigen::Isometry3d with_roll = SampleWorldFromCamera(Camera(30, 0, 90), rolled);
    ASSERT_NEAR(with_tilt.translation().norm(), distance, 1e-9);
    ASSERT_EQ(with_roll.translation().norm(), distance);
    ASSERT_GT(TiltDeg(with_tilt), 0);
  }
  EXPECT_EQ(plain, tilted);
  EXPECT_EQ(plain, rolled);
}

// ranges that see the whole bin rarely are refused before a run, naming the rate and the range
// to lower; the default ranges over the default bin pass, and without the requirement anything
// goes.
TEST(CameraPoseTest, CheckCameraPoseRangesRefusesRareViews) {
  const Intrinsics intrinsics;
  const config::CameraConfig defaults;
  EXPECT_GT(BinInViewRate(defaults, intrinsics, config::BinConfig(), 2000), 0.9);
  EXPECT_NO_THROW(CheckCameraPoseRanges(defaults, intrinsics, config::BinConfig()));
  // a bin that the nominal pose just sees: rolled or tilted views mostly cut a corner off
  config::BinConfig wide;
  wide.set_inner_length_mm(278);
  wide.set_inner_width_mm(203);
  const double rate = BinInViewRate(defaults, intrinsics, wide, 2000);
  EXPECT_LT(rate, 0.2);
  try {
    CheckCameraPoseRanges(defaults, intrinsics, wide);
    ADD_FAILURE() << "no error for a view rate of " << rate;
  } catch (const std::runtime_error& error) {
    const std::string text = error.what();
    EXPECT_NE(text.find("% of the drawn poses"), std::string::npos) << text;
    EXPECT_NE(text.find("camera.roll_max_deg"), std::string::npos) << text;
  }
  config::CameraConfig anything = defaults;
  anything.set_require_bin_in_view(false);
  EXPECT_NO_THROW(CheckCameraPoseRanges(anything, intrinsics, wide));
}

}  // namespace
}  // namespace stackgen
