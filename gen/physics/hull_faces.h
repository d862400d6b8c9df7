#pragma once

#include <Eigen/Geometry>
#include <vector>

namespace stackgen {

/// One planar face of a convex hull.
struct HullFace {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // outward unit normal, object frame
  double area_mm2 = 0;
  Eigen::Vector3d centroid_mm = Eigen::Vector3d::Zero();  // object frame
};

/// The planar faces of the convex hull of `points_mm` (object frame, millimetres): coplanar hull
/// triangles (normals within 0.5 degrees) merge into one face. Faces come numbered by decreasing
/// area; faces of equal area (to 1e-6 relative) by their normal, x then y then z ascending, so the
/// numbering is a pure function of the part's shape. Throws std::runtime_error if the points span
/// no volume.
std::vector<HullFace> HullFaces(const std::vector<Eigen::Vector3d>& points_mm);

/// The index of the face in `faces` whose outward normal points most nearly straight down (world
/// -Z) for an object whose orientation in the world is `world_from_object`: the face it rests on.
/// -1 when `faces` is empty.
int RestingFace(const std::vector<HullFace>& faces, const Eigen::Matrix3d& world_from_object);

}  // namespace stackgen
