// The visible fraction measured on real renders: an object alone is fully visible, one half
// covered by another object is about half visible.

#include <gtest/gtest.h>

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
  const std::vector<cv::Mat> silhouettes = renderer.RenderSilhouettes(camera, items);
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
  return LabelInstances(rendered.instance, silhouettes, objects, camera.world_from_camera, 0.3,
                        false);
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

}  // namespace
}  // namespace stackgen
