#include "gen/physics/convex_pieces.h"

#include <HACD/hacdHACD.h>
#include <LinearMath/btConvexHullComputer.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <tuple>

namespace stackgen {
namespace {

namespace fs = std::filesystem;

// bump when the decomposition or the file format changes: old cache files are then ignored
constexpr char kCacheVersion[] = "stackgen-hacd-v1";

// a convex part's hull keeps at most this many vertices (else it is simplified)
constexpr int kMaxHullVertices = 256;
// the most triangles a part mesh may have to be decomposed with HACD
constexpr int64_t kMaxDecompositionTriangles = 20000;

// HACD works on coordinates scaled so the part's largest extent is this long
constexpr double kHacdExtent = 1000.0;

std::string FormatBox(const Eigen::AlignedBox3d& box) {
  std::ostringstream text;
  text << "[" << box.min().x() << ", " << box.min().y() << ", " << box.min().z() << "] .. ["
       << box.max().x() << ", " << box.max().y() << ", " << box.max().z() << "] mm";
  return text.str();
}

// A convex hull as planes n.x <= d (unit n) and triangles, from btConvexHullComputer.
struct Hull {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<std::array<int, 3>> triangles;  // counter-clockwise seen from outside
  std::vector<std::pair<Eigen::Vector3d, double>> planes;
};

Hull ComputeHull(const std::vector<Eigen::Vector3d>& points) {
  Hull hull;
  if (points.size() < 4) return hull;
  btConvexHullComputer computer;
  computer.compute(points[0].data(), sizeof(Eigen::Vector3d), static_cast<int>(points.size()), 0,
                   0);
  // use the input points (exact), not the hull's single-precision copies
  for (int i = 0; i < computer.vertices.size(); ++i) {
    hull.vertices.push_back(points[computer.original_vertex_index[i]]);
  }
  for (int f = 0; f < computer.faces.size(); ++f) {
    const btConvexHullComputer::Edge* first = &computer.edges[computer.faces[f]];
    std::vector<int> face = {first->getSourceVertex()};
    for (const btConvexHullComputer::Edge* e = first->getNextEdgeOfFace(); e != first;
         e = e->getNextEdgeOfFace()) {
      face.push_back(e->getSourceVertex());
    }
    if (face.size() < 3) continue;
    // Newell normal of the face polygon
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < face.size(); ++k) {
      const Eigen::Vector3d& a = hull.vertices[face[k]];
      const Eigen::Vector3d& b = hull.vertices[face[(k + 1) % face.size()]];
      normal += a.cross(b);
      centre += a;
    }
    centre /= static_cast<double>(face.size());
    if (normal.norm() == 0) continue;
    normal.normalize();
    hull.planes.emplace_back(normal, normal.dot(centre));
    for (size_t k = 1; k + 1 < face.size(); ++k) {
      hull.triangles.push_back({face[0], face[k], face[k + 1]});
    }
  }
  return hull;
}

double HullVolume(const Hull& hull) {
  double volume = 0;
  for (const auto& t : hull.triangles) {
    volume += hull.vertices[t[0]].dot(hull.vertices[t[1]].cross(hull.vertices[t[2]])) / 6.0;
  }
  return std::abs(volume);
}

// Drops flat pieces and pieces that lie inside another piece (they add cost, not shape).
std::vector<std::vector<Eigen::Vector3d>> PruneContainedPieces(
    std::vector<std::vector<Eigen::Vector3d>> pieces, double extent_mm) {
  const double tolerance = 1e-4 * extent_mm;
  const double min_volume = 1e-6 * extent_mm * extent_mm * extent_mm;
  std::vector<Hull> hulls;
  std::vector<bool> keep(pieces.size(), true);
  for (size_t i = 0; i < pieces.size(); ++i) {
    hulls.push_back(ComputeHull(pieces[i]));
    if (HullVolume(hulls.back()) <= min_volume) keep[i] = false;
  }
  for (size_t i = 0; i < pieces.size(); ++i) {
    for (size_t j = 0; j < pieces.size() && keep[i]; ++j) {
      if (i == j || !keep[j]) continue;
      const bool inside = std::all_of(pieces[i].begin(), pieces[i].end(), [&](const auto& p) {
        return std::all_of(hulls[j].planes.begin(), hulls[j].planes.end(), [&](const auto& plane) {
          return plane.first.dot(p) <= plane.second + tolerance;
        });
      });
      if (inside) keep[i] = false;
    }
  }
  std::vector<std::vector<Eigen::Vector3d>> kept;
  for (size_t i = 0; i < pieces.size(); ++i) {
    if (keep[i]) kept.push_back(std::move(pieces[i]));
  }
  return kept;
}

// FNV-1a over the mesh content and the settings, as 16 hex digits.
std::string CacheKey(const TriangleMesh& part, const DecompositionSettings& settings) {
  uint64_t hash = 14695981039346656037ull;
  auto add = [&hash](const void* data, size_t size) {
    const auto* bytes = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < size; ++i) {
      hash ^= bytes[i];
      hash *= 1099511628211ull;
    }
  };
  std::ostringstream header;
  header.precision(17);
  header << kCacheVersion << " " << settings.concavity << " " << settings.compacity_weight << " "
         << settings.max_vertices_per_piece << " " << part.positions_mm.size() << " "
         << part.triangles.size();
  add(header.str().data(), header.str().size());
  for (const auto& p : part.positions_mm) add(p.data(), 3 * sizeof(float));
  for (const auto& t : part.triangles) add(t.data(), 3 * sizeof(uint32_t));
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(hash));
  return hex;
}

// Reads a cache file written by WriteCache; returns false if it is missing or unusable.
bool ReadCache(const fs::path& path, std::vector<std::vector<Eigen::Vector3d>>* pieces) {
  std::ifstream in(path);
  if (!in) return false;
  std::vector<std::vector<Eigen::Vector3d>> read;
  std::string line;
  bool header_ok = false;
  while (std::getline(in, line)) {
    if (line.rfind(std::string("# ") + kCacheVersion, 0) == 0) header_ok = true;
    if (line.rfind("o ", 0) == 0) {
      read.emplace_back();
    } else if (line.rfind("v ", 0) == 0) {
      if (read.empty()) return false;
      Eigen::Vector3d p;
      char* end = nullptr;
      const char* cursor = line.c_str() + 2;
      for (int i = 0; i < 3; ++i) {
        p[i] = std::strtod(cursor, &end);
        if (end == cursor) return false;
        cursor = end;
      }
      read.back().push_back(p);
    }
  }
  if (!header_ok || read.empty()) return false;
  for (const auto& piece : read) {
    if (piece.size() < 4) return false;
  }
  *pieces = std::move(read);
  return true;
}

// Writes the pieces (as an OBJ of their hulls, viewable) to a temporary file, then renames it.
void WriteCache(const fs::path& path, const std::vector<std::vector<Eigen::Vector3d>>& pieces,
                const std::string& key) {
  // unique per process and call, so concurrent writers never share a temporary file
  static std::atomic<unsigned> writes{0};
  const fs::path temporary =
      path.string() + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(writes++);
  {
    std::ofstream out(temporary);
    out << "# " << kCacheVersion << " key " << key << ": convex pieces in millimetres\n";
    char number[64];
    size_t offset = 1;
    for (size_t i = 0; i < pieces.size(); ++i) {
      const Hull hull = ComputeHull(pieces[i]);
      out << "o piece_" << i << "\n";
      for (const auto& p : pieces[i]) {
        out << "v";
        for (int k = 0; k < 3; ++k) {
          std::snprintf(number, sizeof(number), " %.17g", p[k]);
          out << number;
        }
        out << "\n";
      }
      // hull faces, by index into this piece's points (hull vertices are a subset of them)
      for (const auto& t : hull.triangles) {
        out << "f";
        for (int k = 0; k < 3; ++k) {
          const auto it = std::find(pieces[i].begin(), pieces[i].end(), hull.vertices[t[k]]);
          out << " " << offset + (it - pieces[i].begin());
        }
        out << "\n";
      }
      offset += pieces[i].size();
    }
    out.flush();
    if (!out) {
      throw std::runtime_error("cannot write convex decomposition cache " + temporary.string());
    }
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error) {
    fs::remove(temporary, error);
    throw std::runtime_error("cannot rename " + temporary.string() + " to " + path.string() + ": " +
                             error.message());
  }
}

// Runs HACD on `part` with vertices welded by position.
std::vector<std::vector<Eigen::Vector3d>> Decompose(const TriangleMesh& part,
                                                    const Eigen::AlignedBox3d& bounds,
                                                    const DecompositionSettings& settings) {
  // weld: HACD walks triangle adjacency, so shared edges need shared vertices
  const Eigen::Vector3d centre = bounds.center();
  const double extent = bounds.sizes().maxCoeff();
  const double scale = kHacdExtent / extent;
  std::map<std::tuple<float, float, float>, long> index_of;
  std::vector<HACD::Vec3<HACD::Real>> points;
  std::vector<long> welded(part.positions_mm.size());
  for (size_t i = 0; i < part.positions_mm.size(); ++i) {
    const Eigen::Vector3f& p = part.positions_mm[i];
    const auto [it, added] =
        index_of.emplace(std::make_tuple(p.x(), p.y(), p.z()), static_cast<long>(points.size()));
    if (added) {
      const Eigen::Vector3d q = (p.cast<double>() - centre) * scale;
      points.emplace_back(q.x(), q.y(), q.z());
    }
    welded[i] = it->second;
  }
  std::vector<HACD::Vec3<long>> triangles;
  for (const auto& t : part.triangles) {
    triangles.emplace_back(welded[t[0]], welded[t[1]], welded[t[2]]);
  }

  // decompose
  HACD::HACD hacd;
  hacd.SetPoints(points.data());
  hacd.SetNPoints(points.size());
  hacd.SetTriangles(triangles.data());
  hacd.SetNTriangles(triangles.size());
  hacd.SetCompacityWeight(settings.compacity_weight);
  hacd.SetVolumeWeight(0.0);
  hacd.SetNClusters(1);
  hacd.SetNVerticesPerCH(static_cast<size_t>(settings.max_vertices_per_piece));
  hacd.SetConcavity(settings.concavity * kHacdExtent);
  hacd.SetAddExtraDistPoints(true);
  hacd.SetAddNeighboursDistPoints(false);
  hacd.SetAddFacesPoints(true);
  if (!hacd.Compute()) throw std::runtime_error("HACD convex decomposition failed");

  // pieces back in millimetres
  std::vector<std::vector<Eigen::Vector3d>> pieces;
  for (size_t c = 0; c < hacd.GetNClusters(); ++c) {
    std::vector<HACD::Vec3<HACD::Real>> hull_points(hacd.GetNPointsCH(c));
    std::vector<HACD::Vec3<long>> hull_triangles(hacd.GetNTrianglesCH(c));
    if (hull_points.empty() || !hacd.GetCH(c, hull_points.data(), hull_triangles.data())) continue;
    std::vector<Eigen::Vector3d> piece;
    for (const auto& q : hull_points) {
      piece.push_back(Eigen::Vector3d(q.X(), q.Y(), q.Z()) / scale + centre);
    }
    pieces.push_back(std::move(piece));
  }
  return PruneContainedPieces(std::move(pieces), extent);
}

// Supplied collision pieces, checked: together they must span the part's box `part_box`, and
// each must have volume.
ConvexPieces SuppliedPieces(const std::vector<TriangleMesh>& supplied,
                            const Eigen::AlignedBox3d& part_box) {
  const double extent = part_box.sizes().maxCoeff();
  ConvexPieces result;
  Eigen::AlignedBox3d pieces_box;
  for (const auto& piece : supplied) {
    std::vector<Eigen::Vector3d> points;
    for (const auto& p : piece.positions_mm) {
      points.push_back(p.cast<double>());
      pieces_box.extend(points.back());
    }
    result.points_mm.push_back(std::move(points));
  }
  const double tolerance = 0.1 * extent;
  if ((pieces_box.min() - part_box.min()).cwiseAbs().maxCoeff() > tolerance ||
      (pieces_box.max() - part_box.max()).cwiseAbs().maxCoeff() > tolerance) {
    throw std::runtime_error("the collision pieces span " + FormatBox(pieces_box) +
                             " but the part spans " + FormatBox(part_box) +
                             "; are they in the part's units and frame?");
  }
  for (size_t i = 0; i < result.points_mm.size(); ++i) {
    if (!(ConvexHullVolume(result.points_mm[i]) > 1e-6 * extent * extent * extent)) {
      throw std::runtime_error("collision piece " + std::to_string(i) +
                               " is flat (its hull has no volume)");
    }
  }
  result.description =
      "compound of " + std::to_string(supplied.size()) + " convex pieces (supplied)";
  return result;
}

// The hull of a finely tessellated convex part from one point per cell of a grid (each Bullet
// contact test walks every hull vertex), coarser until small enough; the hull moves by at most
// a cell's diagonal. `extent`: the part's largest side, mm.
ConvexPieces SimplifiedHull(const Hull& hull, double extent) {
  ConvexPieces result;
  for (int cells = 64; cells >= 4; cells /= 2) {
    const double cell = extent / cells;
    std::map<std::array<int64_t, 3>, Eigen::Vector3d> representative;
    for (const Eigen::Vector3d& v : hull.vertices) {
      const std::array<int64_t, 3> key = {static_cast<int64_t>(std::floor(v.x() / cell)),
                                          static_cast<int64_t>(std::floor(v.y() / cell)),
                                          static_cast<int64_t>(std::floor(v.z() / cell))};
      representative.emplace(key, v);
    }
    std::vector<Eigen::Vector3d> points;
    for (const auto& [key, v] : representative) points.push_back(v);
    const Hull coarse = ComputeHull(points);
    if (static_cast<int>(coarse.vertices.size()) <= kMaxHullVertices || cells == 4) {
      result.points_mm.push_back(coarse.vertices);
      std::ostringstream text;
      text << "convex hull (" << coarse.vertices.size() << " vertices, simplified from "
           << hull.vertices.size() << " on a " << cell << " mm grid)";
      result.description = text.str();
      return result;
    }
  }
  return result;  // unreachable: the coarsest grid always returns
}

}  // namespace

double ConvexHullVolume(const std::vector<Eigen::Vector3d>& points) {
  return HullVolume(ComputeHull(points));
}

ConvexPieces MakeConvexPieces(const TriangleMesh& part, const std::vector<TriangleMesh>& supplied,
                              const std::string& cache_dir, const DecompositionSettings& settings) {
  if (part.triangles.empty()) throw std::runtime_error("the part mesh holds no triangles");
  const Eigen::AlignedBox3d part_box = Bounds(part);
  const double extent = part_box.sizes().maxCoeff();
  ConvexPieces result;

  // supplied pieces: together they must span the part, each must have volume
  if (!supplied.empty()) return SuppliedPieces(supplied, part_box);

  // a convex part is its own hull
  std::vector<Eigen::Vector3d> all_points;
  for (const auto& p : part.positions_mm) all_points.push_back(p.cast<double>());
  const Hull hull = ComputeHull(all_points);
  const double hull_volume = HullVolume(hull);
  if (SignedVolume(part) >= settings.convex_volume_ratio * hull_volume) {
    if (static_cast<int>(hull.vertices.size()) <= kMaxHullVertices) {
      result.points_mm.push_back(hull.vertices);
      result.description = "convex hull (" + std::to_string(hull.vertices.size()) + " vertices)";
      return result;
    }
    // a finely tessellated convex part: a simpler hull
    return SimplifiedHull(hull, extent);
  }

  // a mesh this large takes HACD far too long (minutes and more, with no way to stop it)
  if (static_cast<int64_t>(part.triangles.size()) > kMaxDecompositionTriangles) {
    throw std::runtime_error(
        "the part mesh has " + std::to_string(part.triangles.size()) +
        " triangles, more than the " + std::to_string(kMaxDecompositionTriangles) +
        " a convex decomposition is computed for; give its convex collision pieces "
        "(collision_mesh) or a simplified mesh");
  }

  // otherwise HACD, from the cache when it holds this mesh and these settings
  const std::string key = CacheKey(part, settings);
  fs::path cache_path;
  if (!cache_dir.empty()) {
    std::error_code error;
    fs::create_directories(cache_dir, error);
    if (error) {
      throw std::runtime_error("cannot create the convex decomposition cache directory " +
                               cache_dir + ": " + error.message());
    }
    cache_path = fs::path(cache_dir) / ("hacd-" + key + ".obj");
    if (ReadCache(cache_path, &result.points_mm)) {
      result.description = "HACD decomposition, " + std::to_string(result.points_mm.size()) +
                           " pieces (cached, " + cache_path.string() + ")";
      return result;
    }
  }
  result.points_mm = Decompose(part, part_box, settings);
  if (result.points_mm.empty()) {
    throw std::runtime_error("HACD convex decomposition produced no pieces with volume");
  }
  result.description =
      "HACD decomposition, " + std::to_string(result.points_mm.size()) + " pieces (computed";
  if (!cache_path.empty()) {
    WriteCache(cache_path, result.points_mm, key);
    result.description += ", cached to " + cache_path.string();
  }
  result.description += ")";
  return result;
}

}  // namespace stackgen
