// The visible fraction measured on real renders: an object alone is fully visible, one half
// covered by another object is about half visible, one cut by the image edge counts its whole
// silhouette.

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include <vector>

#include "gen/annotate/labels.h"
#include "gen/annotate/rle.h"
#include "gen/render/renderer.h"
#include "tests/support/meshes.h"

namespace stackgen {
namespace {

// a 320 x 240 camera 400 mm above the origin, looking straight down (image y along world -y).
CameraModel TopCamera() {
  CameraModel camera;
  camera.width = 320;
  camera.height = 240;
  camera.fx = camera.fy = 400;
  camera.cx = 159.5;
  camera.cy = 119.5;
  camera.world_from_camera.linear() << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  camera.world_from_camera.translation() = Eigen::Vector3d(0, 0, 400);
  return camera;
}

// renders the items and labels the objects among them (instance ids 1, 2, ... in item order).
std::vector<instance> RenderAndLabel(Renderer& renderer, const std::vector<DrawItem>& items) {
  const CameraModel camera = TopCamera();
  const RenderResult rendered = renderer.Render(camera, {Light{}}, RenderOptions{}, items);
  std::vector<cv::Mat> silhouettes, beyond;
  renderer.RenderSilhouettes(camera, items, &silhouettes, &beyond);
  std::vector<ObjectTruth> objects;
  for (const DrawItem& item : items) {
    if (item.instance_id == 0) continue;
    ObjectTruth object;
    object.instance_id = item.instance_id;
    object.class_id = 1;
    object.class_name = "box";
    object.world_from_object = item.world_from_object;
    objects.push_back(object);
  }
  return LabelInstances(rendered.instance, silhouettes, beyond, objects, camera.world_from_camera,
                        0.3, false);
}

DrawItem Item(int mesh_id, uint16_t instance_id, const Eigen::Vector3d& position) {
  DrawItem item;
  item.mesh_id = mesh_id;
  item.instance_id = instance_id;
  item.world_from_object.translation() = position;
  return item;
}

// An object with nothing in front of it has visib_fract exactly 1 and its full mask is its
// visible mask.
TEST(VisibilityTest, UnoccludedObjectIsFullyVisible) {
  Renderer renderer(320, 240);
  const int box = renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 40, 10)));
  const std::vector<instance> labels =
      RenderAndLabel(renderer, {Item(box, 1, Eigen::Vector3d(0, 0, 5))});
  ASSERT_EQ(labels.size(), 1u);
  EXPECT_GT(labels[0].px_count_all, 1000);
  EXPECT_EQ(labels[0].px_count_visib, labels[0].px_count_all);
  EXPECT_DOUBLE_EQ(labels[0].visib_fract, 1.0);
  EXPECT_EQ(labels[0].mask_obj_rle, labels[0].mask_visib_rle);
  EXPECT_TRUE(labels[0].annotated);
}

// A plate whose edge lies over the box's centre line hides half of it: visib_fract about 0.5,
// whether the plate is another object or an unlabelled one (the bin, a distractor); the full
// mask still covers the whole box.
TEST(VisibilityTest, HalfCoveredObjectIsHalfVisible) {
  Renderer renderer(320, 240);
  const int box = renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 40, 10)));
  // a plate over y in [0, 40], x in [-40, 40]: its edge y = 0 projects onto the box's centre line
  const int plate =
      renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(-40, 0, 30), Eigen::Vector3f(40, 40, 32)));
  const instance alone = RenderAndLabel(renderer, {Item(box, 1, Eigen::Vector3d(0, 0, 5))})[0];
  for (const uint16_t plate_id : {uint16_t{2}, uint16_t{0}}) {
    const std::vector<instance> labels = RenderAndLabel(
        renderer,
        {Item(box, 1, Eigen::Vector3d(0, 0, 5)), Item(plate, plate_id, Eigen::Vector3d::Zero())});
    const instance& covered = labels[0];
    EXPECT_NEAR(covered.visib_fract, 0.5, 0.02) << "plate id " << plate_id;
    EXPECT_EQ(covered.px_count_all, alone.px_count_all);
    EXPECT_EQ(covered.mask_obj_rle, alone.mask_obj_rle);
    EXPECT_EQ(RleArea(covered.mask_visib_rle), static_cast<uint64_t>(covered.px_count_visib));
    EXPECT_TRUE(covered.annotated);  // 0.5 >= 0.3
    if (plate_id == 2) {
      EXPECT_DOUBLE_EQ(labels[1].visib_fract, 1.0);
    }
  }
}

// The pixel centres inside the convex hull of the 8 corners of box [lo, hi] as TopCamera sees
// it, over the image and a margin of its size on each side: those inside by more than 0.01 px
// (`surely`) and those inside or within 0.01 px of the outline (`maybe`), with the boxes
// [x0, y0, x1, y1] of each set. Whatever rounding the rasteriser does lies between the two.
struct AnalyticSilhouette {
  int64_t surely = 0, maybe = 0;
  cv::Rect surely_box, maybe_box;
};
AnalyticSilhouette ProjectBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  const CameraModel camera = TopCamera();
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();
  std::vector<cv::Point2f> corners;
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3d p =
        camera_from_world *
        Eigen::Vector3d(k & 1 ? hi.x() : lo.x(), k & 2 ? hi.y() : lo.y(), k & 4 ? hi.z() : lo.z());
    corners.emplace_back(static_cast<float>(camera.fx * p.x() / p.z() + camera.cx),
                         static_cast<float>(camera.fy * p.y() / p.z() + camera.cy));
  }
  std::vector<cv::Point2f> hull;
  cv::convexHull(corners, hull);
  AnalyticSilhouette result;
  for (int v = -camera.height; v < 2 * camera.height; ++v) {
    for (int u = -camera.width; u < 2 * camera.width; ++u) {
      const double distance = cv::pointPolygonTest(hull, cv::Point2f(u, v), true);
      if (distance > 0.01) {
        ++result.surely;
        result.surely_box |= cv::Rect(u, v, 1, 1);
      }
      if (distance >= -0.01) {
        ++result.maybe;
        result.maybe_box |= cv::Rect(u, v, 1, 1);
      }
    }
  }
  return result;
}

// A box cut by the image's left edge counts its whole silhouette, the part outside the image
// included (as bop_toolkit's calc_gt_info does): px_count_all and bbox_obj match the analytic
// outline, the box starts left of the image, visib_fract is the share inside; the full mask
// holds the part in the image. A box wholly outside the image still has its px_count_all and
// box, and nothing visible.
TEST(VisibilityTest, ObjectCutByTheImageEdgeCountsItsWholeSilhouette) {
  Renderer renderer(320, 240);
  const Eigen::Vector3d lo(-20, -20, -5), hi(20, 20, 5);
  const int box = renderer.AddMesh(testing::BoxMesh(lo.cast<float>(), hi.cast<float>()));
  const Eigen::Vector3d cut_at(-150.3, 10.2, 5), outside_at(-260.7, -30.1, 5);
  const std::vector<instance> labels =
      RenderAndLabel(renderer, {Item(box, 1, cut_at), Item(box, 2, outside_at)});
  ASSERT_EQ(labels.size(), 2u);
  for (int k = 0; k < 2; ++k) {
    const Eigen::Vector3d at = k == 0 ? cut_at : outside_at;
    const AnalyticSilhouette expected = ProjectBox(lo + at, hi + at);
    const instance& label = labels[k];
    SCOPED_TRACE("box " + std::to_string(k + 1));
    EXPECT_GE(label.px_count_all, expected.surely);
    EXPECT_LE(label.px_count_all, expected.maybe);
    const cv::Rect box_obj(label.bbox_obj[0], label.bbox_obj[1], label.bbox_obj[2],
                           label.bbox_obj[3]);
    EXPECT_EQ(box_obj & expected.surely_box, expected.surely_box);
    EXPECT_EQ(box_obj & expected.maybe_box, box_obj);
    EXPECT_LT(label.bbox_obj[0], 0);
    // the full mask: the silhouette's part in the image
    EXPECT_LT(static_cast<int64_t>(RleArea(label.mask_obj_rle)), label.px_count_all);
    EXPECT_EQ(RleArea(label.mask_obj_rle), static_cast<uint64_t>(label.px_count_visib));
  }
  const instance& cut = labels[0];
  EXPECT_GT(cut.px_count_visib, 0);
  EXPECT_DOUBLE_EQ(cut.visib_fract, static_cast<double>(cut.px_count_visib) / cut.px_count_all);
  EXPECT_GT(cut.visib_fract, 0.2);
  EXPECT_LT(cut.visib_fract, 0.8);
  const instance& outside = labels[1];
  EXPECT_EQ(outside.px_count_visib, 0);
  EXPECT_GT(outside.px_count_all, 1000);
  EXPECT_EQ(outside.visib_fract, 0.0);
  EXPECT_FALSE(outside.annotated);
}

}  // namespace
}  // namespace stackgen
