#include "gen/mesh/symmetry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

namespace stackgen {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

// how many vertices and area-spread surface points a candidate rotation is checked on
constexpr int kMaxVertexSamples = 1000;
constexpr int kSurfaceSamples = 1000;
// a mesh unchanged by rotations by these angles about an axis is continuous about it: they are
// no multiple of 360 / n for a small n, so an n-fold symmetric part fails at least one of them
constexpr std::array<double, 4> kContinuousTestAnglesDeg = {7.0, 23.0, 41.0, 97.0};
// n-fold turns tried about a lone principal axis, whatever the vertices suggest
constexpr int kMaxFoldOrder = 36;
// the highest order of turns a vertex match may suggest
constexpr int kMaxTurnOrder = 360;
// entries of a returned matrix or axis closer than this to zero are written as zero
constexpr double kSnapToZero = 1e-9;

// squared distance between two points, summed in a fixed order (the same pair gives the same
// value wherever it is computed)
double SquaredDistance(const Vector3d& a, const Vector3d& b) {
  const double dx = a.x() - b.x();
  const double dy = a.y() - b.y();
  const double dz = a.z() - b.z();
  return dx * dx + dy * dy + dz * dz;
}

// squared distance from p to triangle abc (Ericson, Real-Time Collision Detection, 5.1.5); the
// triangle must not be degenerate
double SquaredDistanceToTriangle(const Vector3d& p, const Vector3d& a, const Vector3d& b,
                                 const Vector3d& c) {
  const Vector3d ab = b - a;
  const Vector3d ac = c - a;
  const Vector3d ap = p - a;
  const double d1 = ab.dot(ap);
  const double d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.squaredNorm();
  const Vector3d bp = p - b;
  const double d3 = ab.dot(bp);
  const double d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.squaredNorm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (ap - d1 / (d1 - d3) * ab).squaredNorm();
  const Vector3d cp = p - c;
  const double d5 = ab.dot(cp);
  const double d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.squaredNorm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (ap - d2 / (d2 - d6) * ac).squaredNorm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
    return (bp - (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)).squaredNorm();
  }
  const double denominator = 1 / (va + vb + vc);
  return (ap - ab * (vb * denominator) - ac * (vc * denominator)).squaredNorm();
}

// answers "is this point within the tolerance of the surface?": a uniform grid whose cells list
// the triangles whose bounding box, grown by the tolerance, overlaps them
class SurfaceProximity {
 public:
  SurfaceProximity(const std::vector<Vector3d>& positions,
                   const std::vector<std::array<uint32_t, 3>>& triangles, double tolerance_mm)
      : positions_(positions), tolerance2_(tolerance_mm * tolerance_mm) {
    // the grid covers the surface grown by the tolerance, about 48 cells along its longest side
    Eigen::AlignedBox3d bounds;
    for (const auto& t : triangles) {
      for (const uint32_t i : t) bounds.extend(positions[i]);
    }
    origin_ = bounds.min().array() - tolerance_mm;
    const Vector3d extent = bounds.sizes().array() + 2 * tolerance_mm;
    cell_mm_ = std::max(extent.maxCoeff() / 48, tolerance_mm);
    for (int k = 0; k < 3; ++k) {
      dims_[k] = std::max(1, static_cast<int>(std::ceil(extent[k] / cell_mm_)));
    }

    // keep the triangles with area (a degenerate one is covered by its neighbours)
    for (const auto& t : triangles) {
      const Vector3d& a = positions[t[0]];
      if ((positions[t[1]] - a).cross(positions[t[2]] - a).squaredNorm() > 0) {
        triangles_.push_back(t);
      }
    }

    // count, then fill, the triangles of each cell (compressed rows)
    cell_start_.assign(static_cast<size_t>(dims_[0]) * dims_[1] * dims_[2] + 1, 0);
    for (int pass = 0; pass < 2; ++pass) {
      std::vector<uint32_t> fill;
      if (pass == 1) {
        for (size_t i = 1; i < cell_start_.size(); ++i) cell_start_[i] += cell_start_[i - 1];
        cell_triangles_.resize(cell_start_.back());
        fill.assign(cell_start_.begin(), cell_start_.end() - 1);
      }
      for (uint32_t index = 0; index < triangles_.size(); ++index) {
        Eigen::AlignedBox3d box;
        for (const uint32_t i : triangles_[index]) box.extend(positions[i]);
        const Eigen::Array3i lo = Cell(box.min().array() - tolerance_mm);
        const Eigen::Array3i hi = Cell(box.max().array() + tolerance_mm);
        for (int z = lo[2]; z <= hi[2]; ++z) {
          for (int y = lo[1]; y <= hi[1]; ++y) {
            for (int x = lo[0]; x <= hi[0]; ++x) {
              const size_t cell = Index(x, y, z);
              if (pass == 0) {
                ++cell_start_[cell + 1];
              } else {
                cell_triangles_[fill[cell]++] = index;
              }
            }
          }
        }
      }
    }
  }

  bool Near(const Vector3d& p) const {
    const Eigen::Array3d cell = (p - origin_).array() / cell_mm_;
    for (int k = 0; k < 3; ++k) {
      if (!(cell[k] >= 0 && cell[k] < dims_[k])) return false;
    }
    const size_t index =
        Index(static_cast<int>(cell[0]), static_cast<int>(cell[1]), static_cast<int>(cell[2]));
    for (uint32_t k = cell_start_[index]; k < cell_start_[index + 1]; ++k) {
      const auto& t = triangles_[cell_triangles_[k]];
      if (SquaredDistanceToTriangle(p, positions_[t[0]], positions_[t[1]], positions_[t[2]]) <=
          tolerance2_) {
        return true;
      }
    }
    return false;
  }

 private:
  Eigen::Array3i Cell(const Eigen::Array3d& p) const {
    Eigen::Array3i cell;
    for (int k = 0; k < 3; ++k) {
      cell[k] =
          std::clamp(static_cast<int>(std::floor((p[k] - origin_[k]) / cell_mm_)), 0, dims_[k] - 1);
    }
    return cell;
  }
  size_t Index(int x, int y, int z) const {
    return (static_cast<size_t>(z) * dims_[1] + y) * dims_[0] + x;
  }

  const std::vector<Vector3d>& positions_;
  const double tolerance2_;
  std::vector<std::array<uint32_t, 3>> triangles_;
  Vector3d origin_;
  double cell_mm_ = 1;
  std::array<int, 3> dims_ = {1, 1, 1};
  std::vector<uint32_t> cell_start_;
  std::vector<uint32_t> cell_triangles_;
};

// the distinct vertex positions (hard edges and seams duplicate them), in a fixed order
std::vector<Vector3d> UniquePositions(const std::vector<Eigen::Vector3f>& positions) {
  std::vector<std::array<float, 3>> sorted;
  sorted.reserve(positions.size());
  for (const auto& p : positions) sorted.push_back({p.x(), p.y(), p.z()});
  std::sort(sorted.begin(), sorted.end());
  sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
  std::vector<Vector3d> unique;
  unique.reserve(sorted.size());
  for (const auto& p : sorted) unique.emplace_back(p[0], p[1], p[2]);
  return unique;
}

// the second moments of the surface about its centroid, weighted by 1 and by the squared
// distance from the centroid, each divided by its total weight (mm^2): every symmetry of the
// surface leaves both unchanged, whatever the tessellation (the integrals are exact)
struct SurfaceMoments {
  Vector3d centroid_mm = Vector3d::Zero();
  double area_mm2 = 0;
  std::array<Matrix3d, 2> tensors;
};

SurfaceMoments ComputeMoments(const std::vector<Vector3d>& positions,
                              const std::vector<std::array<uint32_t, 3>>& triangles) {
  SurfaceMoments moments;
  // centroid: area-weighted triangle centroids
  for (const auto& t : triangles) {
    const Vector3d &a = positions[t[0]], &b = positions[t[1]], &c = positions[t[2]];
    const double area = 0.5 * (b - a).cross(c - a).norm();
    moments.area_mm2 += area;
    moments.centroid_mm += area * (a + b + c) / 3;
  }
  if (!(moments.area_mm2 > 0)) return moments;
  moments.centroid_mm /= moments.area_mm2;

  // the integrands are polynomials of degree 2 and 4: Dunavant's 6-point rule (degree 4) is exact
  constexpr std::array<std::array<double, 4>, 6> kRule = {{
      {0.108103018168070, 0.445948490915965, 0.445948490915965, 0.223381589678011},
      {0.445948490915965, 0.108103018168070, 0.445948490915965, 0.223381589678011},
      {0.445948490915965, 0.445948490915965, 0.108103018168070, 0.223381589678011},
      {0.816847572980459, 0.091576213509771, 0.091576213509771, 0.109951743655322},
      {0.091576213509771, 0.816847572980459, 0.091576213509771, 0.109951743655322},
      {0.091576213509771, 0.091576213509771, 0.816847572980459, 0.109951743655322},
  }};
  std::array<double, 2> weights = {0, 0};
  moments.tensors = {Matrix3d::Zero(), Matrix3d::Zero()};
  for (const auto& t : triangles) {
    const Vector3d a = positions[t[0]] - moments.centroid_mm;
    const Vector3d b = positions[t[1]] - moments.centroid_mm;
    const Vector3d c = positions[t[2]] - moments.centroid_mm;
    const double area = 0.5 * (b - a).cross(c - a).norm();
    for (const auto& q : kRule) {
      const Vector3d x = q[0] * a + q[1] * b + q[2] * c;
      const double w = area * q[3];
      const Matrix3d xx = x * x.transpose();
      moments.tensors[0] += w * xx;
      moments.tensors[1] += w * x.squaredNorm() * xx;
      weights[0] += w;
      weights[1] += w * x.squaredNorm();
    }
  }
  for (int k = 0; k < 2; ++k) {
    if (weights[k] > 0) moments.tensors[k] /= weights[k];
  }
  return moments;
}

// the principal axes of a moment tensor and how many distinct moments it has (1, 2 or 3)
struct PrincipalAxes {
  Matrix3d axes;  // columns, moments ascending
  int distinct = 3;
  int lone_axis = -1;  // with 2 distinct moments, the column of the unrepeated one
};

PrincipalAxes Principal(const Matrix3d& tensor, double equal_mm2) {
  const Eigen::SelfAdjointEigenSolver<Matrix3d> solver(tensor);
  const Vector3d m = solver.eigenvalues();
  PrincipalAxes principal;
  principal.axes = solver.eigenvectors();
  const bool low_equal = m[1] - m[0] <= equal_mm2;
  const bool high_equal = m[2] - m[1] <= equal_mm2;
  if (low_equal && high_equal) {
    principal.distinct = 1;
  } else if (low_equal || high_equal) {
    principal.distinct = 2;
    principal.lone_axis = low_equal ? 2 : 0;
  }
  return principal;
}

// a unit vector, signed so that its largest component is positive
Vector3d Canonical(Vector3d axis) {
  axis.normalize();
  int largest = 0;
  axis.cwiseAbs().maxCoeff(&largest);
  return axis[largest] < 0 ? Vector3d(-axis) : axis;
}

// the rotation by 180 degrees about `axis`
Matrix3d HalfTurn(const Vector3d& axis) {
  const Vector3d u = axis.normalized();
  return 2 * u * u.transpose() - Matrix3d::Identity();
}

// a unit vector perpendicular to `axis`, from the coordinate axis most nearly perpendicular to it
Vector3d Perpendicular(const Vector3d& axis) {
  int most = 0;
  axis.cwiseAbs().minCoeff(&most);
  const Vector3d e = Vector3d::Unit(most);
  return (e - e.dot(axis) * axis).normalized();
}

// the rotation taking the frame spanned by (x0, y0) to the frame spanned by (x1, y1)
Matrix3d FrameToFrame(const Vector3d& x0, const Vector3d& y0, const Vector3d& x1,
                      const Vector3d& y1) {
  const auto frame = [](const Vector3d& x, const Vector3d& y) {
    Matrix3d f;
    f.col(0) = x.normalized();
    f.col(1) = (y - y.dot(f.col(0)) * f.col(0)).normalized();
    f.col(2) = f.col(0).cross(f.col(1));
    return f;
  };
  return frame(x1, y1) * frame(x0, y0).transpose();
}

// tests candidate rotations about the centroid and keeps the accepted ones
class SymmetrySearch {
 public:
  SymmetrySearch(const TriangleMesh& mesh, double tolerance_mm) : tolerance_mm_(tolerance_mm) {
    // the vertices the triangles use (a stray vertex is no part of the surface), checked
    positions_.reserve(mesh.positions_mm.size());
    for (const auto& p : mesh.positions_mm) positions_.push_back(p.cast<double>());
    std::vector<Eigen::Vector3f> used;
    used.reserve(3 * mesh.triangles.size());
    for (const auto& t : mesh.triangles) {
      for (const uint32_t i : t) {
        if (i >= positions_.size()) {
          throw std::invalid_argument("FindSymmetries: triangle vertex index " + std::to_string(i) +
                                      " out of range (" + std::to_string(positions_.size()) +
                                      " vertices)");
        }
        if (!positions_[i].allFinite()) {
          throw std::invalid_argument("FindSymmetries: vertex " + std::to_string(i) +
                                      " is not finite");
        }
        used.push_back(mesh.positions_mm[i]);
      }
    }
    unique_ = UniquePositions(used);

    moments_ = ComputeMoments(positions_, mesh.triangles);
    if (!(moments_.area_mm2 > 0)) {
      throw std::invalid_argument("FindSymmetries: the mesh has no triangle area");
    }
    centroid_ = moments_.centroid_mm;
    for (const auto& p : unique_) radius_mm_ = std::max(radius_mm_, (p - centroid_).norm());
    proximity_ = std::make_unique<SurfaceProximity>(positions_, mesh.triangles, tolerance_mm);
    SampleSurface(mesh.triangles);
  }

  const SurfaceMoments& moments() const { return moments_; }
  const std::vector<Vector3d>& unique() const { return unique_; }
  const Vector3d& centroid() const { return centroid_; }
  double radius_mm() const { return radius_mm_; }
  double tolerance_mm() const { return tolerance_mm_; }

  // true when rotating the surface by `rotation` about the centroid moves no sample point farther
  // than the tolerance from the surface (one-sided: a rotation keeps the area, so one that maps the
  // surface into itself maps it onto itself)
  bool Accepts(const Matrix3d& rotation) const {
    for (const Vector3d& s : samples_) {
      if (!proximity_->Near(centroid_ + rotation * (s - centroid_))) return false;
    }
    return true;
  }

  // true when the surface is unchanged by every rotation about `axis` through the centroid
  bool Continuous(const Vector3d& axis) const {
    for (const double degrees : kContinuousTestAnglesDeg) {
      if (!Accepts(Eigen::AngleAxisd(degrees * M_PI / 180, axis).toRotationMatrix())) {
        return false;
      }
    }
    return true;
  }

  // tests `rotation` unless it is the identity or one already accepted (within the tolerance);
  // keeps it if accepted
  void Try(const Matrix3d& rotation) {
    if (Same(rotation, Matrix3d::Identity()) || Find(accepted_, rotation)) return;
    if (Accepts(rotation)) accepted_.push_back(rotation);
  }

  const std::vector<Matrix3d>& accepted() const { return accepted_; }

 private:
  // two rotations are the same when they move no vertex apart by more than twice the tolerance:
  // two rotations that both pass differ by one that passes within twice the tolerance, so
  // closer ones are one symmetry seen through the tolerance (a rotation by angle t moves a point
  // at distance r from its axis by 2 r sin(t / 2) = r sqrt(3 - trace))
  bool Same(const Matrix3d& a, const Matrix3d& b) const {
    const double trace = (a.transpose() * b).trace();
    return radius_mm_ * std::sqrt(std::max(0.0, 3 - trace)) <= 2 * tolerance_mm_;
  }
  bool Find(const std::vector<Matrix3d>& list, const Matrix3d& rotation) const {
    return std::any_of(list.begin(), list.end(),
                       [&](const Matrix3d& r) { return Same(r, rotation); });
  }

  // the points candidates are checked on: vertices (farthest from the centroid first, as they
  // move most), interleaved with points spread over the triangles by area
  void SampleSurface(const std::vector<std::array<uint32_t, 3>>& triangles) {
    // vertices: every k-th of those sorted by distance from the centroid, the farthest first
    std::vector<Vector3d> vertices = unique_;
    std::stable_sort(vertices.begin(), vertices.end(), [&](const Vector3d& a, const Vector3d& b) {
      return (a - centroid_).squaredNorm() > (b - centroid_).squaredNorm();
    });
    const size_t vertex_count = std::min<size_t>(vertices.size(), kMaxVertexSamples);
    std::vector<Vector3d> vertex_samples;
    for (size_t k = 0; k < vertex_count; ++k) {
      vertex_samples.push_back(vertices[k * vertices.size() / vertex_count]);
    }

    // surface points: stratified over the cumulative area, barycentric coordinates from the R2
    // low-discrepancy sequence (deterministic)
    std::vector<double> cumulative;
    cumulative.reserve(triangles.size());
    double total = 0;
    for (const auto& t : triangles) {
      const Vector3d& a = positions_[t[0]];
      total += 0.5 * (positions_[t[1]] - a).cross(positions_[t[2]] - a).norm();
      cumulative.push_back(total);
    }
    std::vector<Vector3d> surface_samples;
    for (int k = 0; k < kSurfaceSamples; ++k) {
      const double at = (k + 0.5) / kSurfaceSamples * total;
      const size_t index = std::min<size_t>(
          std::lower_bound(cumulative.begin(), cumulative.end(), at) - cumulative.begin(),
          triangles.size() - 1);
      double u = std::fmod(0.5 + k * 0.7548776662466927, 1.0);
      double v = std::fmod(0.5 + k * 0.5698402909980532, 1.0);
      if (u + v > 1) {
        u = 1 - u;
        v = 1 - v;
      }
      const auto& t = triangles[index];
      surface_samples.push_back((1 - u - v) * positions_[t[0]] + u * positions_[t[1]] +
                                v * positions_[t[2]]);
    }

    // interleave
    for (size_t k = 0; k < std::max(vertex_samples.size(), surface_samples.size()); ++k) {
      if (k < vertex_samples.size()) samples_.push_back(vertex_samples[k]);
      if (k < surface_samples.size()) samples_.push_back(surface_samples[k]);
    }
  }

  const double tolerance_mm_;
  std::vector<Vector3d> positions_;
  std::vector<Vector3d> unique_;
  SurfaceMoments moments_;
  Vector3d centroid_;
  double radius_mm_ = 0;
  std::unique_ptr<SurfaceProximity> proximity_;
  std::vector<Vector3d> samples_;
  std::vector<Matrix3d> accepted_;
};

// a candidate rotation and how far the vertex match it came from is off, mm
struct Candidate {
  double residual_mm;
  Matrix3d rotation;
};

// sorts candidates best match first: of rotations equal within the tolerance (a mesh that is not
// quite symmetric, or one whose turns are close to each other) the first accepted is kept, and
// that should be the exact one
void SortByResidual(std::vector<Candidate>* candidates) {
  std::stable_sort(
      candidates->begin(), candidates->end(),
      [](const Candidate& a, const Candidate& b) { return a.residual_mm < b.residual_mm; });
}

// the symmetries about a lone principal axis `axis` (not continuous): the turns about it (their
// order N is the largest n for which every turn by a multiple of 360 / n passes: n <= 36, or
// one suggested by a vertex match), and the half turns across it (one from a vertex match, or
// about a principal axis, times each turn)
void FindAboutLoneAxis(const Vector3d& axis, const Matrix3d& principal_axes,
                       SymmetrySearch* search) {
  const double tolerance = search->tolerance_mm();
  const Vector3d& centroid = search->centroid();
  const auto split = [&](const Vector3d& p) {
    const Vector3d d = p - centroid;
    const double height = d.dot(axis);
    return std::make_pair(height, Vector3d(d - height * axis));
  };

  // the reference vertex: the farthest from the axis
  const std::vector<Vector3d>& unique = search->unique();
  size_t reference = 0;
  double reference_radius = -1;
  for (size_t i = 0; i < unique.size(); ++i) {
    const double radius = split(unique[i]).second.norm();
    if (radius > reference_radius) {
      reference = i;
      reference_radius = radius;
    }
  }

  // vertex matches: on the reference's ring (a turn), or on its mirror image across the centroid
  // (a half turn about the axis bisecting the two, or normal to both when they are opposite)
  std::vector<int> orders;
  for (int n = 2; n <= kMaxFoldOrder; ++n) orders.push_back(n);
  std::vector<Candidate> flips;
  if (reference_radius > tolerance) {
    const auto [height, radial] = split(unique[reference]);
    for (const Vector3d& p : unique) {
      const auto [h, r] = split(p);
      const double off_ring = std::abs(r.norm() - reference_radius);
      if (off_ring > 2 * tolerance) continue;
      if (std::abs(h - height) <= 2 * tolerance) {
        const double angle = std::abs(std::atan2(axis.dot(radial.cross(r)), radial.dot(r)));
        const double turns = 2 * M_PI / std::max(angle, 1e-12);
        if (turns <= kMaxTurnOrder && std::abs(turns - std::round(turns)) < 0.01) {
          orders.push_back(static_cast<int>(std::round(turns)));
        }
      }
      if (std::abs(h + height) <= 2 * tolerance) {
        Vector3d bisector = radial.normalized() + r.normalized();
        if (bisector.norm() < 1e-6) bisector = axis.cross(radial);
        flips.push_back({off_ring + std::abs(h + height), HalfTurn(bisector)});
      }
    }
  }

  // the turns
  std::sort(orders.begin(), orders.end(), std::greater<int>());
  orders.erase(std::unique(orders.begin(), orders.end()), orders.end());
  const auto turn = [&](int k, int n) {
    return Matrix3d(Eigen::AngleAxisd(2 * M_PI * k / n, axis).toRotationMatrix());
  };
  int order = 1;
  for (const int n : orders) {
    bool all = true;
    for (int k = 1; k <= n / 2 && all; ++k) all = search->Accepts(turn(k, n));
    if (all) {
      order = n;
      break;
    }
  }
  for (int k = 1; k < order; ++k) search->Try(turn(k, order));

  // the half turns: the best vertex match that passes (else a principal axis across the lone
  // one), then its products with the turns
  for (int k = 0; k < 3; ++k) {
    const Vector3d across = principal_axes.col(k);
    if (std::abs(across.dot(axis)) < 1e-6) flips.push_back({INFINITY, HalfTurn(across)});
  }
  SortByResidual(&flips);
  for (const Candidate& flip : flips) {
    if (!search->Accepts(flip.rotation)) continue;
    for (int k = 0; k < order; ++k) search->Try(turn(k, order) * flip.rotation);
    break;
  }
}

// candidates when no principal axis stands out (cube, tetrahedron, ...): the rotations taking two
// reference vertices (the farthest from the centroid, and the one farthest from the line through
// it) to vertices at the same distances and the same angle, best match first
void TryVertexPairs(SymmetrySearch* search) {
  const double tolerance = search->tolerance_mm();
  const Vector3d& centroid = search->centroid();
  const std::vector<Vector3d>& unique = search->unique();
  Vector3d first = Vector3d::Zero();
  for (const Vector3d& p : unique) {
    if ((p - centroid).squaredNorm() > first.squaredNorm()) first = p - centroid;
  }
  const Vector3d direction = first.normalized();
  Vector3d second = Vector3d::Zero();
  double second_off_line = 0;
  for (const Vector3d& p : unique) {
    const double off_line = (p - centroid).cross(direction).norm();
    if (off_line > second_off_line) {
      second = p;
      second_off_line = off_line;
    }
  }
  if (second_off_line <= tolerance) return;  // every vertex is on one line
  second -= centroid;

  const auto shell = [&](const Vector3d& d) {
    std::vector<Vector3d> members;
    for (const Vector3d& p : unique) {
      if (std::abs((p - centroid).norm() - d.norm()) <= 2 * tolerance) {
        members.push_back(p - centroid);
      }
    }
    return members;
  };
  const std::vector<Vector3d> firsts = shell(first);
  const std::vector<Vector3d> seconds = shell(second);
  // the angle between the two, as the distance between them
  const double apart = (first - second).norm();
  std::vector<Candidate> candidates;
  for (const Vector3d& a : firsts) {
    for (const Vector3d& b : seconds) {
      const double off_apart = std::abs((a - b).norm() - apart);
      if (off_apart > 4 * tolerance || a.cross(b).norm() < 1e-9) continue;
      const double residual =
          std::abs(a.norm() - first.norm()) + std::abs(b.norm() - second.norm()) + off_apart;
      candidates.push_back({residual, FrameToFrame(first, second, a, b)});
    }
  }
  SortByResidual(&candidates);
  for (const Candidate& c : candidates) search->Try(c.rotation);
}

// the rigid transform of a rotation about the line through `centroid`, tiny entries zeroed
Eigen::Matrix4d AboutPoint(const Matrix3d& rotation, const Vector3d& centroid) {
  Eigen::Matrix4d transform = Eigen::Matrix4d::Identity();
  transform.topLeftCorner<3, 3>() = rotation;
  transform.topRightCorner<3, 1>() = centroid - rotation * centroid;
  return transform.unaryExpr([](double x) { return std::abs(x) < kSnapToZero ? 0.0 : x; });
}

// orders rotations by axis, then by signed angle about it (so the output is stable)
std::tuple<int64_t, int64_t, int64_t, int64_t> SortKey(const Matrix3d& rotation) {
  const Eigen::AngleAxisd angle_axis(rotation);
  const Vector3d axis = Canonical(angle_axis.axis());
  const double angle = axis.dot(angle_axis.axis()) < 0 ? -angle_axis.angle() : angle_axis.angle();
  const auto round = [](double x) { return static_cast<int64_t>(std::llround(x * 1e6)); };
  return {round(axis.x()), round(axis.y()), round(axis.z()),
          round(std::abs(angle) >= M_PI - 1e-6 ? M_PI : angle)};
}

}  // namespace

namespace {

// A lower bound of the squared diameter of `points` to prune with: a few rounds of "the vertex
// farthest from the last one".
double DiameterLowerBound2(const std::vector<Vector3d>& points) {
  const auto farthest_from = [&](const Vector3d& q) {
    size_t best = 0;
    double best2 = -1;
    for (size_t i = 0; i < points.size(); ++i) {
      const double d2 = SquaredDistance(points[i], q);
      if (d2 > best2) {
        best = i;
        best2 = d2;
      }
    }
    return std::make_pair(best, best2);
  };
  double best2 = 0;
  size_t from = 0;
  for (int round = 0; round < 4; ++round) {
    const auto [to, d2] = farthest_from(points[from]);
    best2 = std::max(best2, d2);
    from = to;
  }
  return best2;
}

// A node of a k-d tree of points: its bounding box, its points [begin, end) and its children
// (-1: a leaf).
struct KdNode {
  Eigen::AlignedBox3d box;
  size_t begin, end;
  int children[2] = {-1, -1};
};

// Adds the node of points [begin, end) and its subtree to `nodes` (leaves of at most 8 points,
// split at the median of the box's longest axis, which reorders `points`); returns its index.
int AddKdNode(std::vector<Vector3d>& points, size_t begin, size_t end, std::vector<KdNode>* nodes) {
  const int index = static_cast<int>(nodes->size());
  nodes->push_back({Eigen::AlignedBox3d(), begin, end});
  Eigen::AlignedBox3d box;
  for (size_t i = begin; i < end; ++i) box.extend(points[i]);
  (*nodes)[index].box = box;
  if (end - begin > 8) {
    int axis = 0;
    box.sizes().maxCoeff(&axis);
    const size_t middle = (begin + end) / 2;
    std::nth_element(points.begin() + begin, points.begin() + middle, points.begin() + end,
                     [axis](const Vector3d& a, const Vector3d& b) { return a[axis] < b[axis]; });
    const int left = AddKdNode(points, begin, middle, nodes);
    const int right = AddKdNode(points, middle, end, nodes);
    (*nodes)[index].children[0] = left;
    (*nodes)[index].children[1] = right;
  }
  return index;
}

// A k-d tree of `points` (which it reorders), the root first.
std::vector<KdNode> BuildKdTree(std::vector<Vector3d>* points) {
  std::vector<KdNode> nodes;
  AddKdNode(*points, 0, points->size(), &nodes);
  return nodes;
}

}  // namespace

double MeshDiameter(const TriangleMesh& mesh) {
  std::vector<Vector3d> points = UniquePositions(mesh.positions_mm);
  if (points.size() < 2) return 0;

  // a lower bound to prune with, then a k-d tree of the vertices
  double best2 = DiameterLowerBound2(points);
  const std::vector<KdNode> nodes = BuildKdTree(&points);

  // branch and bound over pairs of nodes: a pair whose boxes are nowhere farther apart than the
  // best distance so far cannot hold a farther pair (the bound is grown by a few ulps, so
  // rounding cannot prune the farthest pair)
  const auto bound2 = [&](int a, int b) {
    const Eigen::AlignedBox3d &p = nodes[a].box, &q = nodes[b].box;
    return (q.max() - p.min()).cwiseMax(p.max() - q.min()).squaredNorm() * (1 + 1e-12);
  };
  std::function<void(int, int)> search = [&](int a, int b) {
    if (bound2(a, b) <= best2) return;
    const KdNode& na = nodes[a];
    const KdNode& nb = nodes[b];
    if (na.children[0] < 0 && nb.children[0] < 0) {
      for (size_t i = na.begin; i < na.end; ++i) {
        for (size_t j = a == b ? i + 1 : nb.begin; j < nb.end; ++j) {
          best2 = std::max(best2, SquaredDistance(points[i], points[j]));
        }
      }
      return;
    }
    if (a == b) {
      const int l = na.children[0], r = na.children[1];
      search(l, r);
      search(l, l);
      search(r, r);
      return;
    }
    // split the larger node; visit the more promising pair first
    const bool split_a =
        nb.children[0] < 0 ||
        (na.children[0] >= 0 && na.box.diagonal().squaredNorm() >= nb.box.diagonal().squaredNorm());
    const int keep = split_a ? b : a;
    int first = (split_a ? na : nb).children[0];
    int second = (split_a ? na : nb).children[1];
    if (bound2(second, keep) > bound2(first, keep)) std::swap(first, second);
    search(first, keep);
    search(second, keep);
  };
  search(0, 0);
  return std::sqrt(best2);
}

MeshSymmetries FindSymmetries(const TriangleMesh& mesh, double tolerance_mm) {
  if (!(tolerance_mm > 0 && std::isfinite(tolerance_mm))) {
    std::ostringstream message;
    message << "FindSymmetries: tolerance_mm must be a positive finite number, got "
            << tolerance_mm;
    throw std::invalid_argument(message.str());
  }
  SymmetrySearch search(mesh, tolerance_mm);
  const Vector3d& centroid = search.centroid();

  // principal axes of both moment tensors: moments closer than a tolerance-sized change of the
  // surface can make are taken as equal; the tensor with the most distinct moments leads
  const double equal_mm2 = 4 * search.radius_mm() * tolerance_mm;
  std::array<PrincipalAxes, 2> principal;
  for (int k = 0; k < 2; ++k) principal[k] = Principal(search.moments().tensors[k], equal_mm2);
  const PrincipalAxes& lead =
      principal[1].distinct > principal[0].distinct ? principal[1] : principal[0];

  // continuous about `axis`: that axis, and one half turn across it if there is one
  const auto continuous_about = [&](const Vector3d& axis) {
    MeshSymmetries symmetries;
    const Matrix3d flip = HalfTurn(Perpendicular(axis));
    if (search.Accepts(flip)) symmetries.discrete.push_back(AboutPoint(flip, centroid));
    const auto snap = [](double x) { return std::abs(x) < kSnapToZero ? 0.0 : x; };
    const Vector3d offset = centroid - centroid.dot(axis) * axis;
    symmetries.continuous.push_back({axis.unaryExpr(snap), offset.unaryExpr(snap)});
    return symmetries;
  };

  // a lone axis: continuous about it? no axis stands out: continuous about one of three
  // perpendicular ones (several: a sphere, refused)?
  const Vector3d lone_axis =
      lead.distinct == 2 ? Canonical(lead.axes.col(lead.lone_axis)) : Vector3d::Zero();
  if (lead.distinct == 2 && search.Continuous(lone_axis)) return continuous_about(lone_axis);
  if (lead.distinct == 1) {
    std::vector<Vector3d> continuous_axes;
    for (int k = 0; k < 3; ++k) {
      const Vector3d axis = Canonical(lead.axes.col(k));
      if (search.Continuous(axis)) continuous_axes.push_back(axis);
    }
    if (continuous_axes.size() >= 2) {
      throw std::runtime_error(
          "FindSymmetries: the mesh is unchanged by rotations about several axes (a sphere?); "
          "BOP's symmetries_continuous cannot describe it");
    }
    if (continuous_axes.size() == 1) return continuous_about(continuous_axes[0]);
  }

  // the candidates: with three distinct moments, the half turns about the principal axes (there
  // can be no other symmetry); about a lone axis, its turns and the half turns across it; when no
  // axis stands out, vertex pairs
  if (lead.distinct == 3) {
    for (int k = 0; k < 3; ++k) search.Try(HalfTurn(lead.axes.col(k)));
  }
  if (lead.distinct == 2) FindAboutLoneAxis(lone_axis, lead.axes, &search);
  if (lead.distinct == 1) TryVertexPairs(&search);

  MeshSymmetries symmetries;
  std::vector<Matrix3d> rotations = search.accepted();
  std::sort(rotations.begin(), rotations.end(),
            [](const Matrix3d& a, const Matrix3d& b) { return SortKey(a) < SortKey(b); });
  for (const Matrix3d& r : rotations) symmetries.discrete.push_back(AboutPoint(r, centroid));
  return symmetries;
}

}  // namespace stackgen
