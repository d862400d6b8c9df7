#include "gen/physics/hull_faces.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "gen/mesh/mesh.h"

namespace stackgen {
namespace {

// the 8 corners of an axis-aligned box centred at `centre`
std::vector<Eigen::Vector3d> BoxCorners(const Eigen::Vector3d& size,
                                        const Eigen::Vector3d& centre = Eigen::Vector3d::Zero()) {
  std::vector<Eigen::Vector3d> corners;
  for (int i = 0; i < 8; ++i) {
    corners.push_back(centre + Eigen::Vector3d((i & 1 ? 0.5 : -0.5) * size.x(),
                                               (i & 2 ? 0.5 : -0.5) * size.y(),
                                               (i & 4 ? 0.5 : -0.5) * size.z()));
  }
  return corners;
}

// A box has six faces, largest first, with outward normals and the right areas and centroids.
TEST(HullFaces, BoxHasSixOutwardFacesLargestFirst) {
  const Eigen::Vector3d centre(5, -3, 2);
  const auto faces = HullFaces(BoxCorners({60, 40, 10}, centre));
  ASSERT_EQ(faces.size(), 6u);
  const double expected_areas[] = {2400, 2400, 600, 600, 400, 400};
  for (size_t f = 0; f < faces.size(); ++f) {
    EXPECT_NEAR(faces[f].area_mm2, expected_areas[f], 1e-6) << f;
    EXPECT_GT((faces[f].centroid_mm - centre).dot(faces[f].normal), 0) << f;
    EXPECT_NEAR(faces[f].normal.cwiseAbs().maxCoeff(), 1.0, 1e-12) << f;
  }
  // equal areas are ordered by normal: -z before +z
  EXPECT_NEAR(faces[0].normal.z(), -1, 1e-12);
  EXPECT_NEAR(faces[1].normal.z(), 1, 1e-12);
  EXPECT_NEAR(faces[0].centroid_mm.z(), centre.z() - 5, 1e-9);
}

// Points inside the hull and extra points on a face do not add faces.
TEST(HullFaces, InnerAndCoplanarPointsAddNoFaces) {
  auto points = BoxCorners({20, 20, 20});
  points.push_back({0, 0, 0});
  points.push_back({3, 4, 10});   // on the top face
  points.push_back({10, 2, -7});  // on the +x face
  EXPECT_EQ(HullFaces(points).size(), 6u);
}

// The resting face is the one whose normal points down in the world.
TEST(HullFaces, RestingFaceFollowsTheRotation) {
  const auto faces = HullFaces(BoxCorners({60, 40, 10}));
  EXPECT_EQ(RestingFace(faces, Eigen::Matrix3d::Identity()), 0);  // -z face down
  // turned 180 degrees about x: the +z face points down
  EXPECT_EQ(RestingFace(faces, Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).matrix()), 1);
  // turned 90 degrees about y: the object's +x axis points down (world -z)
  const Eigen::Matrix3d on_end = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).matrix();
  const int f = RestingFace(faces, on_end);
  EXPECT_NEAR((on_end * faces[f].normal).z(), -1, 1e-12);
  EXPECT_NEAR(faces[f].area_mm2, 400, 1e-6);
  EXPECT_EQ(RestingFace({}, Eigen::Matrix3d::Identity()), -1);
}

// Flat point sets have no hull faces: an error, not a guess.
TEST(HullFaces, FlatPointsThrow) {
  EXPECT_THROW(HullFaces(BoxCorners({10, 10, 0})), std::runtime_error);
  EXPECT_THROW(HullFaces({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}), std::runtime_error);
}

}  // namespace
}  // namespace stackgen
