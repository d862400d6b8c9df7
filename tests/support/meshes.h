#pragma once

// Test helpers: small meshes made in code, and the paths of the shipped models.

#include <Eigen/Core>
#include <string>

#include "gen/mesh/mesh.h"

namespace stackgen {
namespace testing {

/// The path of a shipped model in config/models/.
inline std::string ModelPath(const std::string& name) {
  return std::string(STACKGEN_SOURCE_DIR) + "/config/models/" + name;
}

/// A closed, outward-wound axis-aligned box from lo to hi, mm.
inline TriangleMesh BoxMesh(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  TriangleMesh mesh;
  for (int i = 0; i < 8; ++i) {
    mesh.positions_mm.emplace_back(i & 1 ? hi.x() : lo.x(), i & 2 ? hi.y() : lo.y(),
                                   i & 4 ? hi.z() : lo.z());
    mesh.normals.push_back((mesh.positions_mm.back() - (lo + hi) / 2).normalized());
  }
  mesh.triangles = {{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},
                    {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
  return mesh;
}

/// A closed, outward-wound axis-aligned box of `size` centred at the origin, mm.
inline TriangleMesh BoxMesh(const Eigen::Vector3f& size) { return BoxMesh(-size / 2, size / 2); }

/// A square of side size_mm in the object's z = 0 plane, centred at the origin, normal +z (open:
/// drawn two-sided).
inline TriangleMesh MakeSquare(float size_mm) { return MakeSquareMesh(size_mm); }

}  // namespace testing
}  // namespace stackgen
