#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace stackgen {

/// A triangle mesh in millimetres, in its own (object) frame. Vertices at hard edges are
/// duplicated so every vertex has one normal (flat-shaded CAD parts look right).
struct TriangleMesh {
  std::vector<Eigen::Vector3f> positions_mm;
  /// Unit normal per vertex, same size as positions_mm.
  std::vector<Eigen::Vector3f> normals;
  /// Indices into positions_mm, counter-clockwise seen from outside.
  std::vector<std::array<uint32_t, 3>> triangles;
};

/// Loads every mesh of a model file (any format assimp reads) into one TriangleMesh, scaled by
/// `scale_to_mm`. Throws std::runtime_error naming the file if it is missing or unreadable, holds
/// no triangles, or is degenerate (zero extent or volume).
TriangleMesh LoadMesh(const std::string& path, double scale_to_mm);

/// Loads each mesh of a model file as a separate piece (e.g. the convex pieces of a
/// `*_collision.obj`), scaled by `scale_to_mm`. Throws as LoadMesh.
std::vector<TriangleMesh> LoadMeshPieces(const std::string& path, double scale_to_mm);

/// Signed volume enclosed by the triangles, mm^3 (positive when wound outward).
double SignedVolume(const TriangleMesh& mesh);

/// Axis-aligned bounds of the vertices, mm (empty for a mesh without vertices).
Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh);

/// An open box standing on z = 0 with its inner floor centred at the origin: floor and four walls
/// of thickness `wall_mm` around an inner space of length (x) x width (y) x height (z), mm.
TriangleMesh MakeOpenBinMesh(double inner_length_mm, double inner_width_mm,
                             double inner_height_mm, double wall_mm);

}  // namespace stackgen
