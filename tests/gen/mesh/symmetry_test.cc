#include "gen/mesh/symmetry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "gen/mesh/mesh.h"

namespace stackgen {
namespace {

using Eigen::Matrix3d;
using Eigen::Matrix4d;
using Eigen::Vector3d;

// a flat-shaded mesh (three vertices of its own per triangle, as LoadMesh makes at hard edges)
TriangleMesh FlatMesh(const std::vector<Vector3d>& points,
                      const std::vector<std::array<int, 3>>& triangles) {
  TriangleMesh mesh;
  for (const auto& t : triangles) {
    const Vector3d normal =
        (points[t[1]] - points[t[0]]).cross(points[t[2]] - points[t[0]]).normalized();
    std::array<uint32_t, 3> indices;
    for (int k = 0; k < 3; ++k) {
      indices[k] = static_cast<uint32_t>(mesh.positions_mm.size());
      mesh.positions_mm.push_back(points[t[k]].cast<float>());
      mesh.normals.push_back(normal.cast<float>());
    }
    mesh.triangles.push_back(indices);
  }
  return mesh;
}

// a closed box of `size` centred at the origin, then moved by `pose`
TriangleMesh Box(const Vector3d& size,
                 const Eigen::Isometry3d& pose = Eigen::Isometry3d::Identity()) {
  std::vector<Vector3d> corners;
  for (int z = 0; z < 2; ++z) {
    for (int y = 0; y < 2; ++y) {
      for (int x = 0; x < 2; ++x) {
        corners.push_back(
            pose * Vector3d((x - 0.5) * size.x(), (y - 0.5) * size.y(), (z - 0.5) * size.z()));
      }
    }
  }
  // two triangles per face
  const std::vector<std::array<int, 3>> triangles = {
      {0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},  //
      {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
  return FlatMesh(corners, triangles);
}

// a closed prism along z over a regular n-gon of circumradius `radius`, each cap fanned from its
// first corner (a tessellation with less symmetry than the shape)
TriangleMesh Prism(int n, double radius, double height) {
  std::vector<Vector3d> points;
  for (int z = 0; z < 2; ++z) {
    for (int k = 0; k < n; ++k) {
      const double a = 2 * M_PI * k / n;
      points.emplace_back(radius * std::cos(a), radius * std::sin(a), (z - 0.5) * height);
    }
  }
  std::vector<std::array<int, 3>> triangles;
  for (int k = 0; k < n; ++k) {
    const int k1 = (k + 1) % n;
    triangles.push_back({k, k1, n + k1});
    triangles.push_back({k, n + k1, n + k});
  }
  for (int k = 1; k + 1 < n; ++k) {
    triangles.push_back({0, k + 1, k});
    triangles.push_back({n, n + k, n + k + 1});
  }
  return FlatMesh(points, triangles);
}

// a closed gear-like prism along z: `teeth` rounded teeth (radius 20 +- 3 mm), its outline sampled
// at `samples` points, caps fanned from their centres; 4 x samples triangles
TriangleMesh Gear(int teeth, int samples, double height) {
  std::vector<Vector3d> points;
  for (int z = 0; z < 2; ++z) {
    for (int k = 0; k < samples; ++k) {
      const double a = 2 * M_PI * k / samples;
      const double r = 20 + 3 * std::cos(teeth * a);
      points.emplace_back(r * std::cos(a), r * std::sin(a), (z - 0.5) * height);
    }
  }
  points.emplace_back(0, 0, -height / 2);
  points.emplace_back(0, 0, height / 2);
  std::vector<std::array<int, 3>> triangles;
  for (int k = 0; k < samples; ++k) {
    const int k1 = (k + 1) % samples;
    triangles.push_back({k, k1, samples + k1});
    triangles.push_back({k, samples + k1, samples + k});
    triangles.push_back({2 * samples, k1, k});
    triangles.push_back({2 * samples + 1, samples + k, samples + k1});
  }
  return FlatMesh(points, triangles);
}

// a closed cube of side `side` centred at the origin, each face split into n x n squares
TriangleMesh FineCube(double side, int n) {
  std::vector<Vector3d> points;
  std::vector<std::array<int, 3>> triangles;
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign = -1; sign <= 1; sign += 2) {
      // a grid on the face, wound outward
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      const int first = static_cast<int>(points.size());
      for (int i = 0; i <= n; ++i) {
        for (int j = 0; j <= n; ++j) {
          Vector3d p;
          p[axis] = sign * side / 2;
          p[u] = (static_cast<double>(i) / n - 0.5) * side;
          p[v] = (static_cast<double>(j) / n - 0.5) * side;
          points.push_back(p);
        }
      }
      const auto at = [&](int i, int j) { return first + i * (n + 1) + j; };
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          if (sign > 0) {
            triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
            triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
          } else {
            triangles.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
            triangles.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
          }
        }
      }
    }
  }
  return FlatMesh(points, triangles);
}

// a closed UV sphere (poles on z) with `rings` x `segments` quads
TriangleMesh Sphere(double radius, int rings, int segments) {
  std::vector<Vector3d> points = {{0, 0, radius}, {0, 0, -radius}};
  for (int i = 1; i < rings; ++i) {
    const double polar = M_PI * i / rings;
    for (int k = 0; k < segments; ++k) {
      const double a = 2 * M_PI * k / segments;
      points.emplace_back(radius * std::sin(polar) * std::cos(a),
                          radius * std::sin(polar) * std::sin(a), radius * std::cos(polar));
    }
  }
  const auto ring = [&](int i, int k) { return 2 + (i - 1) * segments + (k % segments); };
  std::vector<std::array<int, 3>> triangles;
  for (int k = 0; k < segments; ++k) {
    triangles.push_back({0, ring(1, k), ring(1, k + 1)});
    triangles.push_back({1, ring(rings - 1, k + 1), ring(rings - 1, k)});
    for (int i = 1; i + 1 < rings; ++i) {
      triangles.push_back({ring(i, k), ring(i + 1, k), ring(i + 1, k + 1)});
      triangles.push_back({ring(i, k), ring(i + 1, k + 1), ring(i, k + 1)});
    }
  }
  return FlatMesh(points, triangles);
}

// a model shipped in config/models/ (millimetres)
TriangleMesh Shipped(const std::string& name) {
  return LoadMesh(std::string(STACKGEN_SOURCE_DIR) + "/config/models/" + name, 1.0);
}

// the symmetries at BOP's usual tolerance (1% of the diameter), printed
MeshSymmetries Find(const std::string& what, const TriangleMesh& mesh) {
  const MeshSymmetries symmetries = FindSymmetries(mesh, 0.01 * MeshDiameter(mesh));
  const Eigen::IOFormat row(6, 0, ", ", ", ", "", "", "[", "]");
  std::cout << what << " (" << mesh.triangles.size() << " triangles, diameter "
            << MeshDiameter(mesh) << " mm): " << symmetries.discrete.size() << " discrete, "
            << symmetries.continuous.size() << " continuous\n";
  for (const Matrix4d& t : symmetries.discrete) {
    const Eigen::AngleAxisd r(Matrix3d(t.topLeftCorner<3, 3>()));
    std::cout << "  discrete " << r.angle() * 180 / M_PI << " deg about "
              << r.axis().transpose().format(row)
              << ", row-major: " << Matrix4d(t.transpose()).reshaped().transpose().format(row)
              << "\n";
  }
  for (const ContinuousSymmetry& c : symmetries.continuous) {
    std::cout << "  continuous axis " << c.axis.transpose().format(row) << " offset "
              << c.offset_mm.transpose().format(row) << "\n";
  }
  return symmetries;
}

// every vertex of `mesh`, moved by `transform`, lands within `tolerance_mm` of a vertex
void ExpectVerticesMapToVertices(const TriangleMesh& mesh, const Matrix4d& transform,
                                 double tolerance_mm) {
  // the distinct vertices, sorted by x, so the candidates for a point are a short run
  std::set<std::array<float, 3>> distinct;
  for (const auto& p : mesh.positions_mm) distinct.insert({p.x(), p.y(), p.z()});
  std::vector<Vector3d> vertices;
  for (const auto& p : distinct) vertices.emplace_back(p[0], p[1], p[2]);
  const auto by_x = [](const Vector3d& v, double x) { return v.x() < x; };
  const Eigen::Affine3d moved(transform);
  for (const Vector3d& p : vertices) {
    const Vector3d q = moved * p;
    double nearest = INFINITY;
    for (auto v = std::lower_bound(vertices.begin(), vertices.end(), q.x() - tolerance_mm, by_x);
         v != vertices.end() && v->x() <= q.x() + tolerance_mm; ++v) {
      nearest = std::min(nearest, (*v - q).norm());
    }
    ASSERT_LE(nearest, tolerance_mm)
        << "vertex " << p.transpose() << " moved to " << q.transpose() << " by\n"
        << transform;
  }
}

// `transform` is rigid with a proper rotation (det +1) and not the identity
void ExpectProperRigid(const Matrix4d& transform) {
  const Matrix3d r = transform.topLeftCorner<3, 3>();
  EXPECT_TRUE((r.transpose() * r).isApprox(Matrix3d::Identity(), 1e-9)) << transform;
  EXPECT_NEAR(r.determinant(), 1.0, 1e-9) << transform;
  EXPECT_EQ(transform.row(3), Eigen::RowVector4d(0, 0, 0, 1)) << transform;
  EXPECT_FALSE(transform.isApprox(Matrix4d::Identity(), 1e-6)) << transform;
}

// the rotation angle of a transform, degrees
double AngleDeg(const Matrix4d& transform) {
  return Eigen::AngleAxisd(Matrix3d(transform.topLeftCorner<3, 3>())).angle() * 180 / M_PI;
}

// The diameter of a box, turned and moved off the origin, is its space diagonal.
TEST(MeshDiameterTest, BoxIsItsSpaceDiagonal) {
  const Eigen::Isometry3d pose =
      Eigen::Translation3d(120, -40, 35) * Eigen::AngleAxisd(0.7, Vector3d(1, 2, 3).normalized());
  EXPECT_NEAR(MeshDiameter(Box({40, 25, 12}, pose)), std::sqrt(40 * 40 + 25 * 25 + 12 * 12), 1e-4);
}

// The pruned search finds the same farthest pair as trying every pair (random clouds, fixed seed).
TEST(MeshDiameterTest, MatchesBruteForce) {
  std::mt19937 random(7);
  std::normal_distribution<double> normal(0, 1);
  std::uniform_real_distribution<double> noise(-0.5, 0.5);
  for (int cloud = 0; cloud < 5; ++cloud) {
    TriangleMesh mesh;
    for (int i = 0; i < 3000; ++i) {
      // a squashed ellipsoid shell with noise, so many pairs come close to the diameter
      const Vector3d p = Vector3d(normal(random), normal(random), normal(random)).normalized();
      mesh.positions_mm.push_back((p.cwiseProduct(Vector3d(50, 40 + cloud, 10)) +
                                   Vector3d(noise(random), noise(random), noise(random)))
                                      .cast<float>());
    }
    double brute = 0;
    for (size_t i = 0; i < mesh.positions_mm.size(); ++i) {
      for (size_t j = i + 1; j < mesh.positions_mm.size(); ++j) {
        // summed in the same order as MeshDiameter, so the same pair gives the same value
        const Eigen::Vector3d d =
            mesh.positions_mm[i].cast<double>() - mesh.positions_mm[j].cast<double>();
        brute = std::max(brute, std::sqrt(d.x() * d.x() + d.y() * d.y() + d.z() * d.z()));
      }
    }
    EXPECT_EQ(MeshDiameter(mesh), brute) << "cloud " << cloud;
  }
}

// A 50k-vertex sphere (every vertex extreme: the worst case for pruning) has its pole-to-pole
// diameter (its speed is for a benchmark, not a test).
TEST(MeshDiameterTest, FiftyThousandVertexSphere) {
  const TriangleMesh sphere = Sphere(30, 224, 224);
  ASSERT_GE(sphere.positions_mm.size(), 50000u * 3);  // flat-shaded: 3 per triangle
  EXPECT_NEAR(MeshDiameter(sphere), 60, 1e-5);
}

// An irregular tetrahedron has no symmetry at all.
TEST(FindSymmetriesTest, AsymmetricMeshHasNone) {
  const TriangleMesh mesh = FlatMesh({{0, 0, 0}, {30, 0, 0}, {5, 20, 0}, {8, 6, 15}},
                                     {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}});
  const MeshSymmetries symmetries = Find("irregular tetrahedron", mesh);
  EXPECT_TRUE(symmetries.discrete.empty());
  EXPECT_TRUE(symmetries.continuous.empty());
}

// A box turned and moved off the origin has exactly three half turns, each of which (translation
// included) maps every corner onto a corner.
TEST(FindSymmetriesTest, MovedBoxHasThreeHalfTurnsAboutItsCentre) {
  const Eigen::Isometry3d pose =
      Eigen::Translation3d(120, -40, 35) * Eigen::AngleAxisd(0.7, Vector3d(1, 2, 3).normalized());
  const TriangleMesh box = Box({40, 25, 12}, pose);
  const MeshSymmetries symmetries = Find("moved box", box);
  ASSERT_EQ(symmetries.discrete.size(), 3u);
  EXPECT_TRUE(symmetries.continuous.empty());
  for (const Matrix4d& t : symmetries.discrete) {
    ExpectProperRigid(t);
    EXPECT_NEAR(AngleDeg(t), 180, 1e-6);
    ExpectVerticesMapToVertices(box, t, 1e-4);
    // the box centre stays put
    EXPECT_LT((Eigen::Affine3d(t) * pose.translation() - pose.translation()).norm(), 1e-4);
  }
}

// A cube has the 23 rotations of the octahedral group; a regular tetrahedron the 11 of the
// tetrahedral one (isotropic moments: found from vertex pairs, not principal axes).
TEST(FindSymmetriesTest, CubeAndRegularTetrahedron) {
  const TriangleMesh cube = Box({20, 20, 20}, Eigen::Isometry3d(Eigen::Translation3d(5, 6, 7)));
  const MeshSymmetries cube_symmetries = Find("cube", cube);
  EXPECT_EQ(cube_symmetries.discrete.size(), 23u);
  for (const Matrix4d& t : cube_symmetries.discrete) {
    ExpectProperRigid(t);
    ExpectVerticesMapToVertices(cube, t, 1e-4);
  }

  const TriangleMesh tetrahedron =
      FlatMesh({{10, 10, 10}, {10, -10, -10}, {-10, 10, -10}, {-10, -10, 10}},
               {{0, 1, 2}, {0, 3, 1}, {0, 2, 3}, {1, 3, 2}});
  const MeshSymmetries tetrahedron_symmetries = Find("regular tetrahedron", tetrahedron);
  EXPECT_EQ(tetrahedron_symmetries.discrete.size(), 11u);
  for (const Matrix4d& t : tetrahedron_symmetries.discrete) {
    ExpectProperRigid(t);
    ExpectVerticesMapToVertices(tetrahedron, t, 1e-4);
  }
}

// A hexagonal prism with asymmetrically fanned caps has the 11 rotations of D6: five about its
// axis and six half turns across it (the tessellation does not matter).
TEST(FindSymmetriesTest, HexagonalPrismIsDihedral) {
  const TriangleMesh prism = Prism(6, 20, 10);
  const MeshSymmetries symmetries = Find("hexagonal prism", prism);
  ASSERT_EQ(symmetries.discrete.size(), 11u);
  EXPECT_TRUE(symmetries.continuous.empty());
  int about_axis = 0;
  for (const Matrix4d& t : symmetries.discrete) {
    ExpectProperRigid(t);
    ExpectVerticesMapToVertices(prism, t, 1e-4);
    if (std::abs(t(2, 2) - 1) < 1e-9) ++about_axis;
  }
  EXPECT_EQ(about_axis, 5);
}

// A 48-tooth gear has the 95 rotations of D48: turns by 7.5 degrees, beyond the n-fold turns
// tried (n <= 36), come from matching vertices, and it is not mistaken for continuous.
TEST(FindSymmetriesTest, HighOrderGearIsDihedral) {
  const TriangleMesh gear = Gear(48, 960, 10);
  const MeshSymmetries symmetries = FindSymmetries(gear, 0.01 * MeshDiameter(gear));
  EXPECT_TRUE(symmetries.continuous.empty());
  ASSERT_EQ(symmetries.discrete.size(), 95u);
  int smallest_turns = 0;
  for (const Matrix4d& t : symmetries.discrete) {
    ExpectProperRigid(t);
    ExpectVerticesMapToVertices(gear, t, 1e-3);  // exact, though near-misses pass the tolerance
    if (std::abs(AngleDeg(t) - 7.5) < 1e-3) ++smallest_turns;
  }
  EXPECT_EQ(smallest_turns, 2);  // +-7.5 degrees about z
}

// A 32-tooth gear has the 63 rotations of D32, not those of a higher order whose first turn
// (by 360 / 33 ... 360 / 36 degrees) is within the tolerance of one of its turns.
TEST(FindSymmetriesTest, NearbyTurnOrdersAreNotTaken) {
  const TriangleMesh gear = Gear(32, 640, 10);
  const MeshSymmetries symmetries = FindSymmetries(gear, 0.01 * MeshDiameter(gear));
  EXPECT_TRUE(symmetries.continuous.empty());
  EXPECT_EQ(symmetries.discrete.size(), 63u);
  for (const Matrix4d& t : symmetries.discrete) ExpectVerticesMapToVertices(gear, t, 1e-3);
}

// A cube split finer than the tolerance still gives its 23 rotations exactly (vertex pairs near
// the corners pass the tolerance too; the best match is kept).
TEST(FindSymmetriesTest, FinelySplitCubeIsExact) {
  const TriangleMesh cube = FineCube(20, 80);
  const MeshSymmetries symmetries = FindSymmetries(cube, 0.01 * MeshDiameter(cube));
  EXPECT_EQ(symmetries.discrete.size(), 23u);
  for (const Matrix4d& t : symmetries.discrete) {
    const Matrix3d r = t.topLeftCorner<3, 3>();
    EXPECT_TRUE(r.isApprox(r.array().round().matrix(), 1e-6)) << r;  // signed permutations
  }
}

// Meshes of about 10k triangles: a 12-tooth gear (D12: 11 turns about its axis, 12 half turns
// across it) and a finely split cube (no principal axis stands out: 23).
TEST(FindSymmetriesTest, TenThousandTriangles) {
  const TriangleMesh gear = Gear(12, 2520, 10);
  ASSERT_EQ(gear.triangles.size(), 10080u);
  const MeshSymmetries gear_symmetries = FindSymmetries(gear, 0.01 * MeshDiameter(gear));
  const TriangleMesh cube = FineCube(20, 29);
  ASSERT_EQ(cube.triangles.size(), 10092u);
  const MeshSymmetries cube_symmetries = FindSymmetries(cube, 0.01 * MeshDiameter(cube));
  EXPECT_EQ(gear_symmetries.discrete.size(), 23u);
  EXPECT_TRUE(gear_symmetries.continuous.empty());
  EXPECT_EQ(cube_symmetries.discrete.size(), 23u);
}

// An open bin (surface only, no volume) keeps its half turn about z and nothing else.
TEST(FindSymmetriesTest, OpenBinHasOneHalfTurn) {
  const TriangleMesh bin = MakeOpenBinMesh(100, 60, 40, 3);
  const MeshSymmetries symmetries = Find("open bin", bin);
  ASSERT_EQ(symmetries.discrete.size(), 1u);
  const Matrix3d rotation = symmetries.discrete[0].topLeftCorner<3, 3>();
  EXPECT_TRUE(rotation.isApprox(Vector3d(-1, -1, 1).asDiagonal().toDenseMatrix(), 1e-9));
  ExpectVerticesMapToVertices(bin, symmetries.discrete[0], 1e-4);
}

// The tolerance decides: a 40 x 40.2 mm block is square within 0.5 mm (quarter turns about z
// count), and is not within 0.05 mm.
TEST(FindSymmetriesTest, ToleranceDecidesNearSymmetries) {
  const TriangleMesh block = Box({40, 40.2, 12});
  EXPECT_EQ(FindSymmetries(block, 0.5).discrete.size(), 7u);   // D4
  EXPECT_EQ(FindSymmetries(block, 0.05).discrete.size(), 3u);  // D2
}

// A 64-sided cylinder moved off the origin is continuous about its axis (offset: the axis point
// nearest the origin), and its one half turn across the axis maps it onto itself.
TEST(FindSymmetriesTest, MovedCylinderIsContinuous) {
  TriangleMesh cylinder = Prism(64, 10, 30);
  for (auto& p : cylinder.positions_mm) p += Eigen::Vector3f(10, 20, 30);
  const MeshSymmetries symmetries = Find("moved cylinder", cylinder);
  ASSERT_EQ(symmetries.continuous.size(), 1u);
  EXPECT_TRUE(symmetries.continuous[0].axis.isApprox(Vector3d::UnitZ(), 1e-9));
  EXPECT_TRUE(symmetries.continuous[0].offset_mm.isApprox(Vector3d(10, 20, 0), 1e-6))
      << symmetries.continuous[0].offset_mm;
  ASSERT_EQ(symmetries.discrete.size(), 1u);
  ExpectProperRigid(symmetries.discrete[0]);
  EXPECT_NEAR(AngleDeg(symmetries.discrete[0]), 180, 1e-6);
  ExpectVerticesMapToVertices(cylinder, symmetries.discrete[0], 1e-4);
}

// A sphere is continuous about every axis, which BOP cannot describe: refused.
TEST(FindSymmetriesTest, SphereIsRefused) {
  const TriangleMesh sphere = Sphere(20, 24, 48);
  EXPECT_THROW(FindSymmetries(sphere, 0.4), std::runtime_error);
}

// A tolerance that is not a positive number is refused.
TEST(FindSymmetriesTest, BadToleranceIsRefused) {
  const TriangleMesh box = Box({40, 25, 12});
  EXPECT_THROW(FindSymmetries(box, 0), std::invalid_argument);
  EXPECT_THROW(FindSymmetries(box, -1), std::invalid_argument);
  EXPECT_THROW(FindSymmetries(box, NAN), std::invalid_argument);
}

// The shipped dowel pin (24-sided, along x) is continuous about x through its centre, with one
// half turn across it.
TEST(FindSymmetriesTest, ShippedDowelPin) {
  const TriangleMesh pin = Shipped("dowel_pin.obj");
  const MeshSymmetries symmetries = Find("dowel_pin.obj", pin);
  ASSERT_EQ(symmetries.continuous.size(), 1u);
  EXPECT_TRUE(symmetries.continuous[0].axis.isApprox(Vector3d::UnitX(), 1e-9));
  EXPECT_LT(symmetries.continuous[0].offset_mm.norm(), 1e-6);
  ASSERT_EQ(symmetries.discrete.size(), 1u);
  const Matrix4d& flip = symmetries.discrete[0];
  ExpectProperRigid(flip);
  EXPECT_NEAR(AngleDeg(flip), 180, 1e-6);
  EXPECT_NEAR(flip(0, 0), -1, 1e-9);  // the flip turns x around
  ExpectVerticesMapToVertices(pin, flip, 1e-4);
}

// The shipped foam block (40 x 25 x 12 mm, sides all different) has exactly the three half turns
// about x, y and z.
TEST(FindSymmetriesTest, ShippedFoamBlock) {
  const TriangleMesh block = Shipped("foam_block.obj");
  const MeshSymmetries symmetries = Find("foam_block.obj", block);
  EXPECT_TRUE(symmetries.continuous.empty());
  ASSERT_EQ(symmetries.discrete.size(), 3u);
  std::vector<Matrix3d> expected = {Vector3d(1, -1, -1).asDiagonal(),
                                    Vector3d(-1, 1, -1).asDiagonal(),
                                    Vector3d(-1, -1, 1).asDiagonal()};
  for (const Matrix4d& t : symmetries.discrete) {
    ExpectProperRigid(t);
    EXPECT_TRUE(Vector3d(t.topRightCorner<3, 1>()).isZero(1e-9));
    ExpectVerticesMapToVertices(block, t, 1e-4);
    int matches = 0;
    const Matrix3d rotation = t.topLeftCorner<3, 3>();
    for (const Matrix3d& r : expected) matches += rotation.isApprox(r, 1e-9);
    EXPECT_EQ(matches, 1) << t;
  }
}

// The shipped corner connector is an L of two equal 55 x 55 x 6 plates, a gusset at x = 0 and a
// hole in each plate 40 mm from the inner corner: swapping the plates (y' = 27.5 - z,
// z' = 27.5 - y) and mirroring x is a half turn about the line through (0, 27.5, 0) along
// (0, -1, 1), its only symmetry (the x mirror alone is improper, so BOP leaves it out).
TEST(FindSymmetriesTest, ShippedCornerConnector) {
  const TriangleMesh connector = Shipped("corner_connector.obj");
  const MeshSymmetries symmetries = Find("corner_connector.obj", connector);
  EXPECT_TRUE(symmetries.continuous.empty());
  ASSERT_EQ(symmetries.discrete.size(), 1u);
  Matrix4d expected;
  expected << -1, 0, 0, 0,  //
      0, 0, -1, 27.5,       //
      0, -1, 0, 27.5,       //
      0, 0, 0, 1;
  EXPECT_TRUE(symmetries.discrete[0].isApprox(expected, 1e-6)) << symmetries.discrete[0];
  ExpectProperRigid(symmetries.discrete[0]);
  ExpectVerticesMapToVertices(connector, symmetries.discrete[0], 1e-3);
}

}  // namespace
}  // namespace stackgen
