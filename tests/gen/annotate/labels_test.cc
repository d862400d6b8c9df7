#include "gen/annotate/labels.h"

#include <stdexcept>

#include <gtest/gtest.h>

#include "gen/annotate/pose.h"
#include "gen/annotate/rle.h"

namespace stackgen {
namespace {

constexpr int kHeight = 10;
constexpr int kWidth = 12;

cv::Mat Silhouette(const cv::Rect& rect) {
  cv::Mat mask = cv::Mat::zeros(kHeight, kWidth, CV_8UC1);
  mask(rect).setTo(255);
  return mask;
}

Eigen::Isometry3d Pose(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation) {
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.linear() = rotation;
  transform.translation() = translation;
  return transform;
}

std::array<int32_t, 4> Box(const int32_t box[4]) { return {box[0], box[1], box[2], box[3]}; }

// The scene used below, 12 x 10 pixels:
//   object 1: silhouette x 2..7, y 2..5 (24 px); object 2 lies on it, x 5..10, y 2..5 (24 px), so
//   half of object 1 (columns 5..7) is hidden;
//   object 3: silhouette x 0..1, y 8..9 (4 px) entirely under object 4 (same place, in front);
//   object 5: outside the image, empty silhouette.
struct Scene {
  cv::Mat instance_map = cv::Mat::zeros(kHeight, kWidth, CV_16UC1);
  std::vector<cv::Mat> silhouettes;
  std::vector<ObjectTruth> objects;
  Eigen::Isometry3d world_from_camera =
      Pose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
           Eigen::Vector3d(5.0, -5.0, 600.0));

  Scene() {
    const cv::Rect rects[5] = {{2, 2, 6, 4}, {5, 2, 6, 4}, {0, 8, 2, 2}, {0, 8, 2, 2}, {}};
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(30 * M_PI / 180, Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(20 * M_PI / 180, Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitX()))
                                         .toRotationMatrix();
    for (int i = 0; i < 5; ++i) {
      silhouettes.push_back(Silhouette(rects[i]));
      objects.push_back({i + 1, i < 2 ? 1 : 2, i < 2 ? "connector" : "bolt",
                         Pose(i == 0 ? rotation : Eigen::Matrix3d::Identity(),
                              Eigen::Vector3d(10.0 * i, 20.0, 30.0))});
    }
    // paint back to front: 1, then 2 over it; 3, then 4 over it
    instance_map(rects[0]).setTo(1);
    instance_map(rects[1]).setTo(2);
    instance_map(rects[2]).setTo(3);
    instance_map(rects[3]).setTo(4);
  }
};

// Object 2 covering half of object 1 gives visib_fract 0.5 and 1.0; boxes and counts are exact.
TEST(LabelsTest, HalfCoveredObject) {
  const Scene scene;
  const std::vector<stackgen::instance> labels =
      LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                     scene.world_from_camera, 0.3, false);
  ASSERT_EQ(labels.size(), 5u);

  const stackgen::instance& one = labels[0];
  EXPECT_EQ(one.instance_id, 1);
  EXPECT_EQ(one.class_id, 1);
  EXPECT_EQ(one.class_name, "connector");
  EXPECT_EQ(one.px_count_all, 24);
  EXPECT_EQ(one.px_count_visib, 12);
  EXPECT_DOUBLE_EQ(one.visib_fract, 0.5);
  EXPECT_TRUE(one.annotated);
  EXPECT_EQ(Box(one.bbox_obj), (std::array<int32_t, 4>{2, 2, 6, 4}));
  EXPECT_EQ(Box(one.bbox_visib), (std::array<int32_t, 4>{2, 2, 3, 4}));
  // its visible mask: zeros up to (x 2, y 2), then 4 ones per column for 3 columns
  const cv::Mat visible = DecodeRle(one.mask_visib_rle, kHeight, kWidth);
  EXPECT_EQ(cv::countNonZero(visible), 12);
  EXPECT_EQ(cv::countNonZero(visible(cv::Rect(2, 2, 3, 4))), 12);
  EXPECT_EQ(StringToRuns(one.mask_visib_rle), (std::vector<uint32_t>{22, 4, 6, 4, 6, 4, 74}));

  const stackgen::instance& two = labels[1];
  EXPECT_EQ(two.px_count_all, 24);
  EXPECT_EQ(two.px_count_visib, 24);
  EXPECT_DOUBLE_EQ(two.visib_fract, 1.0);
  EXPECT_TRUE(two.annotated);
  EXPECT_EQ(Box(two.bbox_obj), (std::array<int32_t, 4>{5, 2, 6, 4}));
  EXPECT_EQ(Box(two.bbox_visib), (std::array<int32_t, 4>{5, 2, 6, 4}));
  EXPECT_EQ(RleArea(two.mask_visib_rle), 24u);
  EXPECT_EQ(RleBbox(two.mask_visib_rle, kHeight, kWidth), (std::array<int, 4>{5, 2, 6, 4}));

  // the full (amodal) mask is the whole silhouette, hidden half included
  EXPECT_EQ(RleArea(one.mask_obj_rle), 24u);
  EXPECT_EQ(RleBbox(one.mask_obj_rle, kHeight, kWidth), (std::array<int, 4>{2, 2, 6, 4}));
  EXPECT_FALSE(one.ignored);
}

// A fully hidden object and one outside the image have visib_fract 0 and are not annotated.
TEST(LabelsTest, HiddenAndOutsideObjects) {
  const Scene scene;
  const std::vector<stackgen::instance> labels =
      LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                     scene.world_from_camera, 0.0, false);
  const stackgen::instance& hidden = labels[2];
  EXPECT_EQ(hidden.px_count_all, 4);
  EXPECT_EQ(hidden.px_count_visib, 0);
  EXPECT_EQ(hidden.visib_fract, 0.0);
  EXPECT_FALSE(hidden.annotated);  // even with threshold 0: nothing visible
  EXPECT_EQ(Box(hidden.bbox_obj), (std::array<int32_t, 4>{0, 8, 2, 2}));
  EXPECT_EQ(Box(hidden.bbox_visib), (std::array<int32_t, 4>{0, 0, 0, 0}));
  EXPECT_EQ(RleArea(hidden.mask_visib_rle), 0u);
  const stackgen::instance& front = labels[3];
  EXPECT_EQ(front.visib_fract, 1.0);
  EXPECT_EQ(Box(front.bbox_visib), (std::array<int32_t, 4>{0, 8, 2, 2}));
  const stackgen::instance& outside = labels[4];
  EXPECT_EQ(outside.px_count_all, 0);
  EXPECT_EQ(outside.visib_fract, 0.0);
  EXPECT_FALSE(outside.annotated);
  EXPECT_EQ(Box(outside.bbox_obj), (std::array<int32_t, 4>{0, 0, 0, 0}));
}

// The threshold decides `annotated`: 0.6 drops the half-covered object.
TEST(LabelsTest, ThresholdDecidesAnnotated) {
  const Scene scene;
  const auto labels = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                     scene.world_from_camera, 0.6, false);
  EXPECT_FALSE(labels[0].annotated);
  EXPECT_TRUE(labels[1].annotated);
  const auto at_half = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                      scene.world_from_camera, 0.5, false);
  EXPECT_TRUE(at_half[0].annotated);  // >=, not >
}

// Fewer visible pixels than min_visible_px: not annotated, however visible (object 4 shows all
// of its 4 pixels); under the IGNORE rule an ignore region.
TEST(LabelsTest, TooFewPixelsAreNotAnnotated) {
  const Scene scene;
  const auto at_four = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                      scene.world_from_camera, 0.3, true, 4);
  EXPECT_EQ(at_four[3].px_count_visib, 4);
  EXPECT_TRUE(at_four[3].annotated);
  const auto at_five = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                      scene.world_from_camera, 0.3, true, 5);
  EXPECT_FALSE(at_five[3].annotated);
  EXPECT_TRUE(at_five[3].ignored);
  EXPECT_TRUE(at_five[1].annotated);  // 24 px
}

// The IGNORE rule keeps a too-hidden but visible object as ignored; nothing visible is neither.
TEST(LabelsTest, IgnoreRuleMarksOccludedObjects) {
  const Scene scene;
  const auto dropped = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                      scene.world_from_camera, 0.6, false);
  EXPECT_FALSE(dropped[0].annotated);
  EXPECT_FALSE(dropped[0].ignored);
  const auto kept = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                   scene.world_from_camera, 0.6, true);
  EXPECT_FALSE(kept[0].annotated);
  EXPECT_TRUE(kept[0].ignored);
  EXPECT_TRUE(kept[1].annotated);
  EXPECT_FALSE(kept[1].ignored);  // annotated objects are never ignored
  EXPECT_FALSE(kept[2].ignored);  // hidden entirely: nothing to ignore
  EXPECT_FALSE(kept[4].ignored);  // outside the image
}

// Both poses and the posture angles come from world_from_object and world_from_camera.
TEST(LabelsTest, PosesAndPosture) {
  const Scene scene;
  const auto labels = LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                                     scene.world_from_camera, 0.3, false);
  const Eigen::Isometry3d world_from_object = FromPoseMessage(labels[0].world_from_object);
  const Eigen::Isometry3d camera_from_object = FromPoseMessage(labels[0].camera_from_object);
  EXPECT_TRUE(world_from_object.isApprox(scene.objects[0].world_from_object, 1e-12));
  EXPECT_TRUE(camera_from_object.isApprox(
      scene.world_from_camera.inverse() * scene.objects[0].world_from_object, 1e-12));
  EXPECT_NEAR(labels[0].posture_deg[0], 30.0, 1e-9);
  EXPECT_NEAR(labels[0].posture_deg[1], 20.0, 1e-9);
  EXPECT_NEAR(labels[0].posture_deg[2], 10.0, 1e-9);
  // camera looks down from z = 600 at (5, -5): object 2 at (10, 20, 30) is 570 mm in front
  EXPECT_NEAR(labels[1].camera_from_object.translation_mm[0], 5.0, 1e-9);
  EXPECT_NEAR(labels[1].camera_from_object.translation_mm[1], -25.0, 1e-9);
  EXPECT_NEAR(labels[1].camera_from_object.translation_mm[2], 570.0, 1e-9);
}

// Inputs that disagree are refused.
TEST(LabelsTest, BadInputsThrow) {
  Scene scene;
  const auto label = [&](double min_visib_fract) {
    return LabelInstances(scene.instance_map, scene.silhouettes, {}, scene.objects,
                          scene.world_from_camera, min_visib_fract, false);
  };
  EXPECT_THROW(label(1.5), std::runtime_error);
  scene.silhouettes[1] = cv::Mat::zeros(kHeight + 1, kWidth, CV_8UC1);
  EXPECT_THROW(label(0.3), std::runtime_error);
  scene = Scene();
  scene.silhouettes.pop_back();
  EXPECT_THROW(label(0.3), std::runtime_error);
  scene = Scene();
  scene.objects[1].instance_id = 1;
  EXPECT_THROW(label(0.3), std::runtime_error);
  scene = Scene();
  scene.instance_map.convertTo(scene.instance_map, CV_8UC1);
  EXPECT_THROW(label(0.3), std::runtime_error);
}

}  // namespace
}  // namespace stackgen
