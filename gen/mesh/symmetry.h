#pragma once

#include <vector>

#include <Eigen/Core>

#include "gen/mesh/mesh.h"

namespace stackgen {

/// A continuous rotational symmetry: the mesh is unchanged by any rotation about the line through
/// offset_mm along axis (BOP models_info.json, "symmetries_continuous").
struct ContinuousSymmetry {
  Eigen::Vector3d axis;       // unit vector, mesh frame; its largest component is positive
  Eigen::Vector3d offset_mm;  // the point of the line nearest the mesh origin, mm, mesh frame
};

/// The symmetries of a mesh in its own frame (millimetres), as BOP's models_info.json records
/// them: a pose of the mesh is ambiguous under each of them.
struct MeshSymmetries {
  /// BOP "symmetries_discrete": rigid transforms [R t; 0 0 0 1] (x -> R x + t, t in mm; det R =
  /// +1, so mirror images are never listed), identity excluded, each mapping the mesh onto itself
  /// within the tolerance. With a continuous symmetry, only one 180-degree flip (when there is
  /// one), about the perpendicular axis nearest a coordinate axis: BOP combines the two lists, and
  /// the continuous rotations turn that flip into every other one. Ordered by rotation axis, then
  /// angle.
  std::vector<Eigen::Matrix4d> discrete;
  /// BOP "symmetries_continuous": empty, or one axis (a mesh symmetric about several axes, a
  /// sphere, is not supported: FindSymmetries throws).
  std::vector<ContinuousSymmetry> continuous;
};

/// Largest distance between two vertices of `mesh` (all of positions_mm, used by triangles or
/// not), mm: BOP's "diameter". Exact (a branch-and-bound search over vertex pairs, not an
/// estimate); 0 for fewer than two vertices.
double MeshDiameter(const TriangleMesh& mesh);

/// Finds the symmetries of `mesh`: the proper rotations, about lines through the centroid of its
/// surface, that map the surface onto itself within a surface distance tolerance of
/// `tolerance_mm`. A rotation is accepted when every sample point of the surface (up to 1000 of the
/// vertices the triangles use, and 1000 points spread over the triangles by area, both chosen
/// deterministically), moved by the rotation, lies within tolerance_mm of the unmoved surface
/// (point-to-triangle distance). Rotations that move no vertex apart by more than 2 x tolerance_mm
/// count as one, the best vertex match first found. The surface alone counts: open meshes work,
/// inside and outside are not told apart. A mesh that passes rotations by 7, 23, 41 and 97 degrees
/// about an axis is continuous about it.
///
/// Pass about 1% of MeshDiameter: much less and the facets of curved faces (a 24-sided pin) hide a
/// continuous symmetry; much more and features up to that size (a small hole, a chamfer) are
/// ignored, so a part that is not quite symmetric gets symmetries it lacks.
///
/// Candidates: with three distinct principal moments of the surface (second moments weighted by 1
/// and by the squared distance from the centroid), the half turns about the principal axes, which
/// are all there can be; with one lone principal axis, the turns about it (order n <= 36, or
/// higher where a vertex match suggests it; the largest n for which every multiple of 360 / n
/// passes) and the half turns across it (from a vertex match taken to its mirror image, times each
/// turn); when all moments are equal (cube, tetrahedron), the rotations taking two reference
/// vertices to vertices. Those from vertex matches can be missed where the tessellation does not
/// follow the symmetry. About 0.1 s for 10k triangles. Throws std::invalid_argument when
/// tolerance_mm is not a positive finite number, a triangle's vertex index is out of range or its
/// vertex not finite, or the triangles have no area; std::runtime_error when the mesh is
/// continuous about two axes (a sphere: BOP cannot describe it).
MeshSymmetries FindSymmetries(const TriangleMesh& mesh, double tolerance_mm);

}  // namespace stackgen
