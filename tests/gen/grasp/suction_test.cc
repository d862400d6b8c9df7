// Suction grasps of gen/grasp/suction.cc on shapes whose answer is known: a full seal at the
// centre of a large flat face, none over an edge or a hole, a covered contact's approach refused;
// and the contacts of gen/grasp/grasp_scene.cc, on what the camera sees and seen from above.
#include "gen/grasp/suction.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "gen/render/renderer.h"
#include "tests/support/cameras.h"
#include "tests/support/meshes.h"

namespace stackgen {
namespace {

// the triangles of several meshes as one
TriangleMesh Joined(const std::vector<TriangleMesh>& pieces) {
  TriangleMesh joined;
  for (const TriangleMesh& piece : pieces) {
    const auto offset = static_cast<uint32_t>(joined.positions_mm.size());
    joined.positions_mm.insert(joined.positions_mm.end(), piece.positions_mm.begin(),
                               piece.positions_mm.end());
    joined.normals.insert(joined.normals.end(), piece.normals.begin(), piece.normals.end());
    for (auto t : piece.triangles) {
      for (auto& index : t) index += offset;
      joined.triangles.push_back(t);
    }
  }
  return joined;
}

const Eigen::Vector3d kUp = Eigen::Vector3d::UnitZ();

Eigen::Isometry3d At(double x, double y, double z) {
  return Eigen::Isometry3d(Eigen::Translation3d(x, y, z));
}

// the centre of a 100 x 100 mm face: every point of a 15 mm cup's disc on it, nothing above;
// at 2 mm from the edge half the disc hangs in the air; the centre of a plate's 10 mm hole
// leaves the cup's middle open (its lip sits on the plate: 16 of 25 points)
TEST(SuctionTest, FullSealOnAFlatFaceNoneOverAnEdgeOrAHole) {
  GraspScene scene;
  const int box = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(100, 100, 20)));
  const int plate = scene.AddMesh(Joined({
      testing::BoxMesh(Eigen::Vector3f(-30, -30, 0), Eigen::Vector3f(-5, 30, 5)),
      testing::BoxMesh(Eigen::Vector3f(5, -30, 0), Eigen::Vector3f(30, 30, 5)),
      testing::BoxMesh(Eigen::Vector3f(-5, 5, 0), Eigen::Vector3f(5, 30, 5)),
      testing::BoxMesh(Eigen::Vector3f(-5, -30, 0), Eigen::Vector3f(5, -5, 5)),
  }));
  scene.AddObject(box, At(0, 0, 10), 1);
  scene.AddObject(plate, At(200, 0, 0), 2);
  SuctionCup cup;
  cup.diameter_mm = 15;

  const SuctionGrasp centre = EvaluateSuction(scene, {0, 0, 20}, kUp, 1, {0, 0, 10}, cup);
  EXPECT_DOUBLE_EQ(centre.seal, 1.0);
  EXPECT_TRUE(centre.approach_clear);
  EXPECT_DOUBLE_EQ(centre.clearance_mm, cup.approach_mm);
  EXPECT_NEAR(centre.com_offset_mm, 0, 1e-9);

  const SuctionGrasp edge = EvaluateSuction(scene, {48, 0, 20}, kUp, 1, {0, 0, 10}, cup);
  EXPECT_LT(edge.seal, 0.8);
  EXPECT_GT(edge.seal, 0.3);
  EXPECT_NEAR(edge.com_offset_mm, 48, 1e-6);

  const SuctionGrasp hole = EvaluateSuction(scene, {200, 0, 5}, kUp, 2, {200, 0, 2.5}, cup);
  EXPECT_DOUBLE_EQ(hole.seal, 16.0 / 25);
  const SuctionGrasp beside = EvaluateSuction(scene, {215, 15, 5}, kUp, 2, {200, 0, 2.5}, cup);
  EXPECT_DOUBLE_EQ(beside.seal, 1.0);
}

// a contact under another part: the tool meets it after the gap between them; the same contact
// uncovered is clear, and a contact beside a wall within the tool's radius is not
TEST(SuctionTest, CoveredContactsApproachIsRefused) {
  GraspScene scene;
  const int box = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(100, 100, 20)));
  const int slab = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 40, 5)));
  scene.AddObject(box, At(0, 0, 10), 1);
  scene.AddObject(slab, At(-20, 0, 50), 2);  // over x in [-40, 0], bottom at z = 47.5
  SuctionCup cup;
  const SuctionGrasp covered = EvaluateSuction(scene, {-20, 0, 20}, kUp, 1, {0, 0, 10}, cup);
  EXPECT_DOUBLE_EQ(covered.seal, 1.0);
  EXPECT_FALSE(covered.approach_clear);
  EXPECT_NEAR(covered.clearance_mm, 27.5, 0.01);
  const SuctionGrasp open = EvaluateSuction(scene, {30, 30, 20}, kUp, 1, {0, 0, 10}, cup);
  EXPECT_TRUE(open.approach_clear);
  // a 20 mm tool 5 mm from the slab's side (x = 0) touches it
  const SuctionGrasp beside = EvaluateSuction(scene, {5, 0, 20}, kUp, 1, {0, 0, 10}, cup);
  EXPECT_FALSE(beside.approach_clear);
  EXPECT_TRUE(BetterSuction(open, covered));
  EXPECT_FALSE(BetterSuction(covered, open));
}

// a camera above a box: the candidates lie on its pixels, on its top face (normal up), spread
// out, best first; a pixel of the instance map the mesh does not show there is skipped
TEST(SuctionTest, CandidatesOnWhatTheCameraSees) {
  GraspScene scene;
  const int box = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(100, 60, 20)));
  scene.AddObject(box, At(0, 0, 10), 1);
  const CameraModel camera = testing::CameraLookingDown(500);
  // the box's top face: x in [-50, 50], y in [-30, 30] at z = 20, 480 mm from the camera
  cv::Mat ids(240, 320, CV_16UC1, cv::Scalar(0));
  const double scale = 400.0 / 480;
  const auto at = [&](double x, double y) {
    return cv::Point(static_cast<int>(159.5 + x * scale), static_cast<int>(119.5 + y * scale));
  };
  cv::rectangle(ids, at(-49, -29), at(49, 29), cv::Scalar(7), cv::FILLED);
  SuctionCup cup;
  cup.candidates_per_part = 6;
  const std::vector<SuctionGrasp> grasps =
      SuctionGrasps(scene, scene.SeenPoints(camera, ids, 7, 1, cup.candidates_per_part), 1,
                    {0, 0, 10}, cup);
  ASSERT_EQ(grasps.size(), 6u);
  for (size_t k = 0; k < grasps.size(); ++k) {
    const SuctionGrasp& g = grasps[k];
    EXPECT_EQ(ids.at<uint16_t>(g.v, g.u), 7);
    EXPECT_NEAR(g.point_mm.z(), 20, 1e-3);
    EXPECT_NEAR(g.normal.dot(kUp), 1, 1e-6);
    EXPECT_TRUE(g.approach_clear);
    if (k > 0) EXPECT_FALSE(BetterSuction(g, grasps[k - 1])) << k;
  }
  // the first is the deepest pixel, the centre; the others spread at least 10 px apart
  for (size_t a = 0; a < grasps.size(); ++a) {
    for (size_t b = a + 1; b < grasps.size(); ++b) {
      EXPECT_GT(std::hypot(grasps[a].u - grasps[b].u, grasps[a].v - grasps[b].v), 10);
    }
  }
  // pixels beyond the box (the map says 7, the mesh says nothing): skipped
  cv::Mat wrong(240, 320, CV_16UC1, cv::Scalar(0));
  cv::rectangle(wrong, cv::Point(0, 0), cv::Point(30, 30), cv::Scalar(7), cv::FILLED);
  EXPECT_TRUE(scene.SeenPoints(camera, wrong, 7, 1, 6).empty());
}

// seen from above, a box half under a slab: the candidates lie on its uncovered half, on its top
// face, and every one seals; the slab itself is seen whole; an object not placed has none
TEST(SuctionTest, CandidatesFromAboveOnWhatIsUncovered) {
  GraspScene scene;
  const int box = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(100, 60, 20)));
  const int slab = scene.AddMesh(testing::BoxMesh(Eigen::Vector3f(40, 80, 5)));
  scene.AddObject(box, At(0, 0, 10), 1);
  scene.AddObject(slab, At(-30, 0, 60), 2);  // over x in [-50, -10]
  SuctionCup cup;
  cup.candidates_per_part = 5;
  const std::vector<SuctionGrasp> grasps =
      SuctionGrasps(scene, scene.PointsFromAbove(1, cup.candidates_per_part), 1, {0, 0, 10}, cup);
  ASSERT_EQ(grasps.size(), 5u);
  for (const SuctionGrasp& g : grasps) {
    EXPECT_GT(g.point_mm.x(), -10);
    EXPECT_NEAR(g.point_mm.z(), 20, 1e-3);
    EXPECT_NEAR(g.normal.z(), 1, 1e-6);
  }
  EXPECT_TRUE(grasps.front().approach_clear);
  EXPECT_EQ(scene.PointsFromAbove(2, 5).size(), 5u);
  EXPECT_TRUE(scene.PointsFromAbove(3, 5).empty());
}

}  // namespace
}  // namespace stackgen
