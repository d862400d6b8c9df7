#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "gen/mesh/mesh.h"

namespace stackgen {

/// The convex pieces a part collides as, in its object frame (millimetres): each piece is the
/// convex hull of its points.
struct ConvexPieces {
  std::vector<std::vector<Eigen::Vector3d>> points_mm;
  /// One line saying where the pieces come from, e.g. "HACD decomposition, 7 pieces (cached)".
  std::string description;
};

/// Settings of the HACD decomposition; all of them are part of the cache key.
struct DecompositionSettings {
  /// Largest concavity HACD leaves inside one piece, as a fraction of the part's largest extent.
  double concavity = 0.02;
  /// HACD's compacity weight (favours round pieces over long thin ones).
  double compacity_weight = 1e-4;
  /// Most vertices per piece.
  int max_vertices_per_piece = 32;
  /// A mesh whose volume is at least this fraction of its hull's volume counts as convex.
  double convex_volume_ratio = 0.99;
};

/// Chooses the convex pieces of `part` (millimetres, closed): `supplied` when it is not empty
/// (each piece becomes the hull of its vertices), else the convex hull when the part is convex,
/// else a HACD decomposition, cached in `cache_dir` under a key of the mesh content and
/// `settings` (`cache_dir` is created if missing; an empty `cache_dir` disables the cache).
/// Throws std::runtime_error if a supplied piece is flat, if the supplied pieces do not span the
/// part's bounding box (wrong units or frame), if the decomposition fails or the cache directory
/// cannot be created or written.
ConvexPieces MakeConvexPieces(const TriangleMesh& part, const std::vector<TriangleMesh>& supplied,
                              const std::string& cache_dir,
                              const DecompositionSettings& settings = {});

/// Volume of the convex hull of `points`, in the points' unit cubed; 0 if they are coplanar.
double ConvexHullVolume(const std::vector<Eigen::Vector3d>& points);

}  // namespace stackgen
