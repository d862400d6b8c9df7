// Parallel-jaw grasps of gen/grasp/parallel_jaw.cc on shapes whose answer is known: across a box
// between parallel faces, with the whole friction cone to spare; not wider than the jaws open;
// across a wedge only when friction covers its angle; the fingers blocked by a neighbour.
#include "gen/grasp/parallel_jaw.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/meshes.h"

namespace stackgen {
namespace {

Eigen::Isometry3d At(double x, double y, double z) {
  return Eigen::Isometry3d(Eigen::Translation3d(x, y, z));
}

// a closed prism: the triangle (0, 0), (40, 0), (0, 40) in x-z, from y = -30 to 30
TriangleMesh Wedge() {
  TriangleMesh mesh;
  for (const double y : {-30.0, 30.0}) {
    for (const auto& [x, z] : {std::pair<double, double>{0, 0}, {40, 0}, {0, 40}}) {
      mesh.positions_mm.emplace_back(static_cast<float>(x), static_cast<float>(y),
                                     static_cast<float>(z));
      mesh.normals.emplace_back(0.f, 0.f, 1.f);
    }
  }
  mesh.triangles = {{0, 2, 1}, {3, 4, 5}, {0, 1, 4}, {0, 4, 3},
                    {1, 2, 5}, {1, 5, 4}, {2, 0, 3}, {2, 3, 5}};
  return mesh;
}

const Eigen::Vector3d kUp = Eigen::Vector3d::UnitZ();

// a 40 mm wide box gripped from the side of its +x face: the other contact is on its -x face,
// 40 mm away, the closing line along both normals (the whole cone, atan 0.5 = 26.6 degrees, to
// spare); the fingers come down from above, clear; a box 100 mm wide does not fit 80 mm jaws;
// a gripper that would come along the line is refused
TEST(ParallelJawTest, AcrossABoxBetweenParallelFaces) {
  GraspScene scene;
  scene.AddObject(scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 100, 20))), At(0, 0, 10), 1);
  scene.AddObject(scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(100, 40, 20))), At(0, 200, 10),
                  2);
  JawGripper gripper;
  const SurfacePoint side{{20, 10, 10}, {1, 0, 0}, 5, 6};
  const auto grasp = EvaluateJaw(scene, side, 1, {0, 0, 10}, kUp, gripper);
  ASSERT_TRUE(grasp.has_value());
  EXPECT_NEAR((grasp->point_b_mm - Eigen::Vector3d(-20, 10, 10)).norm(), 0, 1e-3);
  EXPECT_NEAR(grasp->width_mm, 40, 1e-3);
  EXPECT_NEAR(grasp->cone_margin_deg, std::atan(0.5) * 180 / M_PI, 1e-3);
  EXPECT_NEAR((grasp->approach - Eigen::Vector3d(0, 0, -1)).norm(), 0, 1e-9);
  EXPECT_TRUE(grasp->approach_clear);
  EXPECT_NEAR(grasp->com_offset_mm, 10, 1e-6);
  EXPECT_EQ(grasp->u, 5);

  const SurfacePoint wide{{50, 200, 10}, {1, 0, 0}, 0, 0};
  EXPECT_FALSE(EvaluateJaw(scene, wide, 2, {0, 200, 10}, kUp, gripper).has_value());
  EXPECT_FALSE(
      EvaluateJaw(scene, side, 1, {0, 0, 10}, Eigen::Vector3d::UnitX(), gripper).has_value());
}

// across a wedge, from its vertical face to its 45-degree face: outside the cone of friction 0.5
// (26.6 degrees), inside that of friction 1.2 (50.2 degrees, 5.2 to spare)
TEST(ParallelJawTest, AcrossAWedgeOnlyWithEnoughFriction) {
  GraspScene scene;
  scene.AddObject(scene.AddMesh(Wedge()), At(0, 0, 0), 1);
  const SurfacePoint vertical{{0, 0, 10}, {-1, 0, 0}, 0, 0};
  JawGripper gripper;
  EXPECT_FALSE(EvaluateJaw(scene, vertical, 1, {13, 0, 13}, kUp, gripper).has_value());
  gripper.friction = 1.2;
  const auto grasp = EvaluateJaw(scene, vertical, 1, {13, 0, 13}, kUp, gripper);
  ASSERT_TRUE(grasp.has_value());
  EXPECT_NEAR(grasp->width_mm, 30, 1e-3);
  EXPECT_NEAR(grasp->cone_margin_deg, std::atan(1.2) * 180 / M_PI - 45, 1e-3);
}

// a box with a taller one beside it: the finger on that side has no room to come down; the other
// contacts of JawGrasps, seen from above, are ordered clear first
TEST(ParallelJawTest, FingersNeedRoomBesideTheContacts) {
  GraspScene scene;
  scene.AddObject(scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 100, 20))), At(0, 0, 10), 1);
  scene.AddObject(scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(10, 100, 60))), At(-30, 0, 30),
                  2);
  JawGripper gripper;
  const auto blocked = EvaluateJaw(scene, {{20, 0, 10}, {1, 0, 0}, 0, 0}, 1, {0, 0, 10}, kUp,
                                   gripper);
  ASSERT_TRUE(blocked.has_value());
  EXPECT_FALSE(blocked->approach_clear);
  EXPECT_LT(blocked->clearance_mm, 1);
  // across the box's length (y) the fingers are clear of the tall box
  const std::vector<JawGrasp> grasps =
      JawGrasps(scene, {{{20, 0, 10}, {1, 0, 0}, 1, 0}, {{0, 50, 10}, {0, 1, 0}, 2, 0}}, 1,
                {0, 0, 10}, {0, 0, 500}, gripper);
  ASSERT_EQ(grasps.size(), 1u) << "100 mm is wider than the jaws open";
  EXPECT_FALSE(grasps[0].approach_clear);
  gripper.max_width_mm = 120;
  const std::vector<JawGrasp> wider =
      JawGrasps(scene, {{{20, 0, 10}, {1, 0, 0}, 1, 0}, {{0, 50, 10}, {0, 1, 0}, 2, 0}}, 1,
                {0, 0, 10}, {0, 0, 500}, gripper);
  ASSERT_EQ(wider.size(), 2u);
  EXPECT_TRUE(wider[0].approach_clear);
  EXPECT_EQ(wider[0].u, 2);
  EXPECT_FALSE(wider[1].approach_clear);
}

}  // namespace
}  // namespace stackgen
