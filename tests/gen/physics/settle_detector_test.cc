#include "gen/physics/settle_detector.h"

#include <cmath>
#include <stdexcept>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

constexpr RestRule kRule{1.0, 1.0, 0.25, 10};

Eigen::Isometry3d Pose(double x_mm, double angle_deg) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translation().x() = x_mm;
  pose.linear() = Eigen::AngleAxisd(angle_deg * M_PI / 180, Eigen::Vector3d::UnitZ()).matrix();
  return pose;
}

// Bodies that do not move settle once the samples span the window, not before.
TEST(SettleDetectorTest, StillBodiesSettleAfterWindow) {
  SettleDetector detector(kRule);
  const std::vector<Eigen::Isometry3d> poses = {Pose(0, 0), Pose(50, 30)};
  for (int k = 0; k <= 24; ++k) EXPECT_FALSE(detector.AddSample(k * 0.01, poses)) << k;
  EXPECT_TRUE(detector.AddSample(0.25, poses));
}

// Samples on a grid that does not divide the window (every 10.5 ms) still settle, a full window
// after the first sample.
TEST(SettleDetectorTest, SettlesWithUnalignedSampling) {
  SettleDetector detector(kRule);
  const std::vector<Eigen::Isometry3d> poses = {Pose(0, 0)};
  bool settled = false;
  int k = 0;
  for (; k < 100 && !settled; ++k) settled = detector.AddSample(k * 0.0105, poses);
  EXPECT_TRUE(settled);
  EXPECT_EQ(k, 25);  // sample 24, at 0.252 s
}

// A slow creep (0.8 mm per 0.1 s) is not settled, though each step is tiny.
TEST(SettleDetectorTest, CreepIsNotSettled) {
  SettleDetector detector(kRule);
  for (int k = 0; k <= 100; ++k) {
    EXPECT_FALSE(detector.AddSample(k * 0.01, {Pose(0, 0), Pose(0.08 * k, 0)})) << k;
  }
}

// A part rocking back and forth by 2 degrees is not settled, though it returns to its start.
TEST(SettleDetectorTest, RockingIsNotSettled) {
  SettleDetector detector(kRule);
  for (int k = 0; k <= 100; ++k) {
    EXPECT_FALSE(detector.AddSample(k * 0.01, {Pose(0, 2 * std::sin(k * 0.5))})) << k;
  }
}

// Motion below both thresholds settles; Reset() starts a new window.
TEST(SettleDetectorTest, SmallMotionSettlesAndResetRestarts) {
  SettleDetector detector(kRule);
  bool settled = false;
  for (int k = 0; k <= 30 && !settled; ++k) {
    settled = detector.AddSample(k * 0.01, {Pose(0.01 * k, 0.01 * k)});
  }
  EXPECT_TRUE(settled);
  detector.Reset();
  EXPECT_FALSE(detector.AddSample(0.31, {Pose(0, 0), Pose(1, 1)}));
  EXPECT_THROW(detector.AddSample(0.32, {Pose(0, 0)}), std::runtime_error);
  EXPECT_THROW(SettleDetector(RestRule{0, 1, 1, 1}), std::runtime_error);
}

// Bodies added between samples (parts released into a pile) are at rest once their own samples
// span the window; the others keep theirs. Fewer bodies than before is an error.
TEST(SettleDetectorTest, AddedBodiesNeedTheirOwnWindow) {
  SettleDetector detector(kRule);
  for (int k = 0; k <= 25; ++k) detector.AddSample(k * 0.01, {Pose(0, 0)});
  EXPECT_TRUE(detector.AtRest(0));
  EXPECT_FALSE(detector.AddSample(0.26, {Pose(0, 0), Pose(50, 0)}));
  EXPECT_TRUE(detector.AtRest(0));
  EXPECT_FALSE(detector.AtRest(1));
  bool settled = false;
  int k = 27;
  for (; k < 100 && !settled; ++k)
    settled = detector.AddSample(k * 0.01, {Pose(0, 0), Pose(50, 0)});
  EXPECT_EQ(k, 52);  // sample 51, at 0.51 s: a window after the second body's first sample
  EXPECT_TRUE(detector.AtRest(1));
  EXPECT_FALSE(detector.AtRest(2));
  EXPECT_THROW(detector.AddSample(0.6, {Pose(0, 0)}), std::runtime_error);
}

// The default settle rule's thresholds (0.1 mm, 0.1 degree over 2 s): a body that moved 0.08 mm
// and turned 0.08 degree within the window is at rest; 0.12 mm, or 0.12 degree, is not.
TEST(SettleDetectorTest, SubMillimetreThresholdsHoldExactly) {
  const RestRule rule{0.1, 0.1, 2, 10};
  for (const auto& [moved_mm, turned_deg, at_rest] : std::vector<std::tuple<double, double, bool>>{
           {0.08, 0.08, true}, {0.12, 0, false}, {0, 0.12, false}}) {
    SettleDetector detector(rule);
    bool settled = false;
    for (int k = 0; k <= 200; ++k) {
      const double f = k / 200.0;  // moving steadily over the window
      settled = detector.AddSample(k * 0.01, {Pose(moved_mm * f, turned_deg * f)});
    }
    EXPECT_EQ(settled, at_rest) << moved_mm << " mm, " << turned_deg << " deg";
  }
}

// A rule of 180 degrees or more does not look at turning: a spinning body that stays in place is
// at rest by it, and not by a rule of 90 degrees.
TEST(SettleDetectorTest, HalfATurnOrMoreIgnoresTurning) {
  SettleDetector ignoring(RestRule{1, 180, 0.25, 1});
  SettleDetector looking(RestRule{1, 90, 0.25, 1});
  bool ignored = false, looked = false;
  for (int k = 0; k <= 30; ++k) {
    ignored = ignoring.AddSample(k * 0.01, {Pose(0, 40.0 * k)});
    looked = looking.AddSample(k * 0.01, {Pose(0, 40.0 * k)});
  }
  EXPECT_TRUE(ignored);
  EXPECT_FALSE(looked);
}

}  // namespace
}  // namespace stackgen
