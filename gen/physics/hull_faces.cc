#include "gen/physics/hull_faces.h"

#include <LinearMath/btConvexHullComputer.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace stackgen {
namespace {

// hull triangles whose normals differ by less than this lie on one face
const double kCoplanarCos = std::cos(0.5 * M_PI / 180);

// areas within this fraction count as equal when numbering faces
constexpr double kEqualAreaFraction = 1e-6;

// a hull triangle
struct Triangle {
  Eigen::Vector3d normal;
  double area;
  Eigen::Vector3d centroid;
};

}  // namespace

std::vector<HullFace> HullFaces(const std::vector<Eigen::Vector3d>& points_mm) {
  if (points_mm.size() < 4) throw std::runtime_error("HullFaces: fewer than 4 points");
  btConvexHullComputer computer;
  computer.compute(points_mm[0].data(), sizeof(Eigen::Vector3d), static_cast<int>(points_mm.size()),
                   0, 0);

  // the hull's polygons as fans of triangles
  std::vector<Triangle> triangles;
  for (int f = 0; f < computer.faces.size(); ++f) {
    const btConvexHullComputer::Edge* first = &computer.edges[computer.faces[f]];
    // Bullet's vertices are floats: take the input's doubles instead
    const auto point = [&](int vertex) -> const Eigen::Vector3d& {
      return points_mm[computer.original_vertex_index[vertex]];
    };
    const Eigen::Vector3d& pa = point(first->getSourceVertex());
    const btConvexHullComputer::Edge* edge = first->getNextEdgeOfFace();
    for (; edge->getNextEdgeOfFace() != first; edge = edge->getNextEdgeOfFace()) {
      const Eigen::Vector3d& pb = point(edge->getSourceVertex());
      const Eigen::Vector3d& pc = point(edge->getTargetVertex());
      const Eigen::Vector3d cross = (pb - pa).cross(pc - pa);
      const double twice_area = cross.norm();
      if (twice_area <= 0) continue;
      triangles.push_back({cross / twice_area, twice_area / 2, (pa + pb + pc) / 3});
    }
  }
  // a flat hull comes back as two faces back to back: refuse anything without volume
  double volume = 0;
  double extent = 0;
  for (const Triangle& t : triangles) volume += t.area * t.normal.dot(t.centroid) / 3;
  for (const auto& p : points_mm) extent = std::max(extent, (p - points_mm[0]).norm());
  if (triangles.empty() || !(volume > 1e-9 * extent * extent * extent)) {
    throw std::runtime_error("HullFaces: the points span no volume");
  }

  // merge coplanar triangles, largest first, into faces with area-weighted normals
  std::sort(triangles.begin(), triangles.end(),
            [](const Triangle& x, const Triangle& y) { return x.area > y.area; });
  std::vector<HullFace> faces;
  std::vector<Eigen::Vector3d> weighted_normals;
  for (const Triangle& t : triangles) {
    size_t f = 0;
    while (f < faces.size() && faces[f].normal.dot(t.normal) < kCoplanarCos) ++f;
    if (f == faces.size()) {
      faces.emplace_back();
      faces.back().area_mm2 = 0;
      weighted_normals.push_back(Eigen::Vector3d::Zero());
    }
    HullFace& face = faces[f];
    face.centroid_mm =
        (face.centroid_mm * face.area_mm2 + t.centroid * t.area) / (face.area_mm2 + t.area);
    face.area_mm2 += t.area;
    weighted_normals[f] += t.normal * t.area;
    face.normal = weighted_normals[f].normalized();
  }

  // numbered by decreasing area, equal areas by normal
  std::sort(faces.begin(), faces.end(), [](const HullFace& x, const HullFace& y) {
    const double tolerance = kEqualAreaFraction * std::max(x.area_mm2, y.area_mm2);
    if (std::abs(x.area_mm2 - y.area_mm2) > tolerance) return x.area_mm2 > y.area_mm2;
    for (int axis = 0; axis < 3; ++axis) {
      if (std::abs(x.normal[axis] - y.normal[axis]) > 1e-9) return x.normal[axis] < y.normal[axis];
    }
    return false;
  });
  return faces;
}

int RestingFace(const std::vector<HullFace>& faces, const Eigen::Matrix3d& world_from_object) {
  int best = -1;
  double best_down = -HUGE_VAL;
  for (size_t f = 0; f < faces.size(); ++f) {
    const double down = -(world_from_object * faces[f].normal).z();
    if (down > best_down) {
      best_down = down;
      best = static_cast<int>(f);
    }
  }
  return best;
}

}  // namespace stackgen
