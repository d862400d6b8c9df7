#include "gen/physics/pile.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <regex>
#include <stdexcept>
#include <string>
#include <vector>

#include "gen/mesh/mesh.h"
#include "tests/support/meshes.h"
#include "tests/support/physics.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using testing::BoxMesh;
using testing::ModelPath;

// the default bin of config/default.pbtxt: 12 connectors lie two to three deep
const BinSpec kBin{200, 150, 100, 8, 0.6, 0.1, {}};

// An L-shaped prism (two 30 x 10 mm legs, 10 mm thick) as one closed mesh: not convex.
constexpr char kLObj[] = R"(v 0 0 0
v 30 0 0
v 30 10 0
v 10 10 0
v 10 30 0
v 0 30 0
v 0 0 10
v 30 0 10
v 30 10 10
v 10 10 10
v 10 30 10
v 0 30 10
f 6 5 4 3 2 1
f 7 8 9 10 11 12
f 1 2 8 7
f 2 3 9 8
f 3 4 10 9
f 4 5 11 10
f 5 6 12 11
f 6 1 7 12
)";

class PileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("stackgen_pile_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  static const TriangleMesh& Connector() {
    static const TriangleMesh mesh = LoadMesh(ModelPath("corner_connector.obj"), 1.0);
    return mesh;
  }
  static const std::vector<TriangleMesh>& ConnectorPieces() {
    static const std::vector<TriangleMesh> pieces =
        LoadMeshPieces(ModelPath("corner_connector_collision.obj"), 1.0);
    return pieces;
  }
  PileSimulator ConnectorSimulator() const {
    return PileSimulator(Connector(), ConnectorPieces(), PartPhysics{}, kBin, SimulationParams{},
                         (dir_ / "cache").string());
  }

  fs::path dir_;
};

// Twelve built-in connectors settle inside the bin without sinking into each other or the bin.
// About one drop in ten loses a part over a wall (the generator redraws those): two piles come
// from the first few seeds.
TEST_F(PileTest, ConnectorPileSettlesInsideBin) {
  const PileSimulator simulator = ConnectorSimulator();
  EXPECT_NE(simulator.CollisionDescription().find("9 convex pieces"), std::string::npos)
      << simulator.CollisionDescription();
  int piles = 0;
  for (uint64_t seed = 1; piles < 2; ++seed) {
    ASSERT_LE(seed, 5u) << "fewer than 2 of 5 drops stayed in the bin";
    const PileResult pile = simulator.Simulate(12, seed);
    ASSERT_EQ(pile.world_from_object.size(), 12u);
    if (pile.num_outside > 0) continue;
    ++piles;
    EXPECT_TRUE(pile.settled) << "seed " << seed;
    EXPECT_EQ(pile.num_outside, 0) << "seed " << seed;
    EXPECT_LT(pile.max_penetration_mm, 0.5) << "seed " << seed;
    EXPECT_GT(pile.simulated_s, 0.25);
    EXPECT_LT(pile.simulated_s, SimulationParams{}.max_sim_time_s);
    // no vertex is below the floor or, below the rim, inside a wall (a part may lean over it)
    for (const auto& world_from_object : pile.world_from_object) {
      for (const auto& v : Connector().positions_mm) {
        const Eigen::Vector3d p = world_from_object * v.cast<double>();
        EXPECT_GT(p.z(), -0.5);
        if (p.z() < kBin.inner_height_mm) {
          EXPECT_LT(std::abs(p.x()), kBin.inner_length_mm / 2 + 0.5);
          EXPECT_LT(std::abs(p.y()), kBin.inner_width_mm / 2 + 0.5);
        }
      }
    }
  }
}

// The same seed gives bit-identical poses, from one simulator or another; other seeds differ.
TEST_F(PileTest, SameSeedIsBitIdentical) {
  const PileSimulator first = ConnectorSimulator();
  const PileSimulator second = ConnectorSimulator();
  const PileResult a = first.Simulate(12, 7);
  const PileResult b = first.Simulate(12, 7);
  const PileResult c = second.Simulate(12, 7);
  const PileResult d = first.Simulate(12, 8);
  ASSERT_EQ(a.world_from_object.size(), 12u);
  for (size_t i = 0; i < a.world_from_object.size(); ++i) {
    EXPECT_TRUE(a.world_from_object[i].matrix() == b.world_from_object[i].matrix()) << i;
    EXPECT_TRUE(a.world_from_object[i].matrix() == c.world_from_object[i].matrix()) << i;
    EXPECT_FALSE(a.world_from_object[i].matrix().isApprox(d.world_from_object[i].matrix(), 1e-3))
        << i;
  }
  EXPECT_EQ(a.simulated_s, b.simulated_s);
  EXPECT_EQ(a.max_penetration_mm, c.max_penetration_mm);
}

// A 20 mm cube comes to rest flat on a face, on the floor.
TEST_F(PileTest, CubeRestsOnFace) {
  const TriangleMesh cube = BoxMesh({-10, -10, -10}, {10, 10, 10});
  const PileSimulator simulator(cube, {}, PartPhysics{}, kBin, SimulationParams{},
                                (dir_ / "cache").string());
  EXPECT_NE(simulator.CollisionDescription().find("convex hull"), std::string::npos)
      << simulator.CollisionDescription();
  for (uint64_t seed : {3u, 4u, 5u}) {
    const PileResult pile = simulator.Simulate(1, seed);
    ASSERT_TRUE(pile.settled) << "seed " << seed;
    const Eigen::Isometry3d& world_from_cube = pile.world_from_object.at(0);
    // one of the cube's axes is vertical within 3 degrees
    const double vertical = world_from_cube.linear().row(2).cwiseAbs().maxCoeff();
    EXPECT_GT(vertical, std::cos(3 * M_PI / 180)) << "seed " << seed;
    // its centre is half its size above the floor (z = 0)
    EXPECT_NEAR(world_from_cube.translation().z(), 10.0, 0.3) << "seed " << seed;
    EXPECT_LT(pile.max_penetration_mm, 0.5);
  }
}

// Mass follows from the mesh volume: a 10 mm cube of density 1000 kg/m^3 weighs 1 g.
TEST_F(PileTest, MassFromVolume) {
  PartPhysics water;
  water.density_kg_m3 = 1000;
  const PileSimulator cube(BoxMesh({0, 0, 0}, {10, 10, 10}), {}, water, kBin, SimulationParams{},
                           "");
  EXPECT_NEAR(cube.mass_kg(), 1e-3, 1e-9);
  // the connector: about 35.5 cm^3 of aluminium
  EXPECT_NEAR(ConnectorSimulator().mass_kg(), 35518.4e-9 * 2700, 1e-4);
}

// A non-convex part without pieces gets a HACD decomposition of more than one piece, cached on
// disk: the second construction reads it back and simulates the same.
TEST_F(PileTest, DecompositionIsCached) {
  const fs::path obj = dir_ / "l.obj";
  std::ofstream(obj) << kLObj;
  const TriangleMesh l_part = LoadMesh(obj.string(), 1.0);
  const std::string cache = (dir_ / "cache" / "nested").string();

  const PileSimulator computed(l_part, {}, PartPhysics{}, kBin, SimulationParams{}, cache);
  std::smatch match;
  const std::string description = computed.CollisionDescription();
  ASSERT_TRUE(std::regex_search(description, match,
                                std::regex("HACD decomposition, ([0-9]+) pieces \\(computed")))
      << description;
  EXPECT_GT(std::stoi(match[1]), 1) << description;
  ASSERT_TRUE(fs::is_directory(cache));
  int files = 0;
  for (const auto& entry : fs::directory_iterator(cache)) {
    EXPECT_EQ(entry.path().extension(), ".obj") << entry.path();  // no temporary left behind
    ++files;
  }
  EXPECT_EQ(files, 1);

  const PileSimulator cached(l_part, {}, PartPhysics{}, kBin, SimulationParams{}, cache);
  EXPECT_NE(cached.CollisionDescription().find("(cached"), std::string::npos)
      << cached.CollisionDescription();
  const PileResult a = computed.Simulate(3, 11);
  const PileResult b = cached.Simulate(3, 11);
  EXPECT_TRUE(a.settled);
  for (size_t i = 0; i < a.world_from_object.size(); ++i) {
    EXPECT_TRUE(a.world_from_object[i].matrix() == b.world_from_object[i].matrix()) << i;
  }
}

// Bad input is refused with a message naming the field or the problem.
TEST_F(PileTest, RefusesBadInput) {
  auto message = [&](auto make) -> std::string {
    try {
      make();
    } catch (const std::runtime_error& e) {
      return e.what();
    }
    return "no exception";
  };
  const TriangleMesh cube = BoxMesh({0, 0, 0}, {10, 10, 10});
  PartPhysics no_density;
  no_density.density_kg_m3 = 0;
  EXPECT_NE(
      message([&] { PileSimulator(cube, {}, no_density, kBin, {}, ""); }).find("density_kg_m3"),
      std::string::npos);
  SimulationParams no_step;
  no_step.time_step_s = 0;
  EXPECT_NE(message([&] { PileSimulator(cube, {}, {}, kBin, no_step, ""); }).find("time_step_s"),
            std::string::npos);
  SimulationParams few_iterations;
  few_iterations.solver_iterations = 4;
  EXPECT_NE(message([&] {
              PileSimulator(cube, {}, {}, kBin, few_iterations, "");
            }).find("solver_iterations"),
            std::string::npos);
  BinSpec no_wall = kBin;
  no_wall.wall_mm = -1;
  EXPECT_NE(message([&] { PileSimulator(cube, {}, {}, no_wall, {}, ""); }).find("wall_mm"),
            std::string::npos);
  // collision pieces in metres for a part in millimetres
  std::vector<TriangleMesh> metres = {BoxMesh({0, 0, 0}, {0.01f, 0.01f, 0.01f})};
  EXPECT_NE(message([&] { PileSimulator(cube, metres, {}, kBin, {}, ""); }).find("units"),
            std::string::npos);
  // an inside-out part has no positive volume
  TriangleMesh inverted = cube;
  for (auto& t : inverted.triangles) std::swap(t[1], t[2]);
  EXPECT_NE(message([&] { PileSimulator(inverted, {}, {}, kBin, {}, ""); }).find("volume"),
            std::string::npos);
  EXPECT_THROW(PileSimulator(cube, {}, {}, kBin, {}, "").Simulate(-1, 0), std::runtime_error);
}

// A torus of n x m quads (two triangles each), radii R and r mm, outward-wound.
TriangleMesh Torus(int n, int m, double big_r, double small_r) {
  TriangleMesh mesh;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < m; ++j) {
      const double u = 2 * M_PI * i / n, v = 2 * M_PI * j / m;
      mesh.positions_mm.emplace_back((big_r + small_r * std::cos(v)) * std::cos(u),
                                     (big_r + small_r * std::cos(v)) * std::sin(u),
                                     small_r * std::sin(v));
      mesh.normals.emplace_back(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
    }
  }
  const auto at = [&](int i, int j) { return static_cast<uint32_t>((i % n) * m + (j % m)); };
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < m; ++j) {
      mesh.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      mesh.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  }
  return mesh;
}

// A UV sphere of n rings x m segments, radius r mm, outward-wound.
TriangleMesh Sphere(int n, int m, double r) {
  TriangleMesh mesh;
  mesh.positions_mm = {{0, 0, static_cast<float>(r)}, {0, 0, static_cast<float>(-r)}};
  for (int i = 1; i < n; ++i) {
    for (int j = 0; j < m; ++j) {
      const double theta = M_PI * i / n, phi = 2 * M_PI * j / m;
      mesh.positions_mm.emplace_back(r * std::sin(theta) * std::cos(phi),
                                     r * std::sin(theta) * std::sin(phi), r * std::cos(theta));
    }
  }
  for (const auto& p : mesh.positions_mm) mesh.normals.push_back(p.normalized());
  const auto at = [&](int i, int j) { return static_cast<uint32_t>(2 + (i - 1) * m + (j % m)); };
  for (int j = 0; j < m; ++j) mesh.triangles.push_back({0, at(1, j), at(1, j + 1)});
  for (int i = 1; i < n - 1; ++i) {
    for (int j = 0; j < m; ++j) {
      mesh.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      mesh.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  }
  for (int j = 0; j < m; ++j) mesh.triangles.push_back({1, at(n - 1, j + 1), at(n - 1, j)});
  return mesh;
}

// A part mesh too large to decompose (a torus of 217,800 triangles, not convex) is refused at
// once, naming the part and saying what to give instead (HACD ran for many minutes on it); a
// finely tessellated convex part (a sphere of 124,500 triangles) gets a simplified hull, said in
// its description, and piles settle.
TEST_F(PileTest, LargeMeshesAreRefusedOrSimplified) {
  PartType torus{Torus(330, 330, 20, 6), {}, PartPhysics{}, "part mesh 'torus.obj'"};
  try {
    PileSimulator({torus}, kBin, SimulationParams{}, "");
    ADD_FAILURE() << "a 217,800-triangle torus was decomposed";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what())
                  .find("part mesh 'torus.obj': the part mesh has 217800 triangles, more than the "
                        "20000 a convex decomposition is computed for"),
              std::string::npos)
        << error.what();
  }
  // a UV sphere of 124,500 triangles: convex, its hull has 45,000 vertices
  PartType ball{Sphere(250, 250, 15), {}, PartPhysics{}, ""};
  const PileSimulator simulator({ball}, kBin, SimulationParams{}, "");
  const std::string description = simulator.CollisionDescription();
  EXPECT_NE(description.find("convex hull ("), std::string::npos) << description;
  EXPECT_NE(description.find("simplified from"), std::string::npos) << description;
  const PileResult pile = simulator.Simulate(3, 1);
  EXPECT_TRUE(pile.settled);
}

// Dropping nothing is a settled, empty pile.
TEST_F(PileTest, EmptyPile) {
  const PileResult pile = ConnectorSimulator().Simulate(0, 1);
  EXPECT_TRUE(pile.settled);
  EXPECT_TRUE(pile.world_from_object.empty());
  EXPECT_EQ(pile.num_outside, 0);
  // simulated on, it is at rest at once
  PileResult after;
  after.settled = false;
  ConnectorSimulator().Simulate({}, 1, kStrictRestRule, &after);
  EXPECT_TRUE(after.settled);
  EXPECT_EQ(after.simulated_s, 0);
}

// A settled pile put back at rest where it lay stays there: Resettle settles at once, nothing
// moves far, and it is bit-identical per input.
TEST_F(PileTest, ResettleKeepsASettledPile) {
  const PileSimulator simulator = ConnectorSimulator();
  // the first seed whose drop settles inside the bin (about one in ten loses a part)
  PileResult pile;
  for (uint64_t seed = 1; !(pile.settled && pile.num_outside == 0) && seed < 10; ++seed) {
    pile = simulator.Simulate(12, seed);
  }
  ASSERT_TRUE(pile.settled);
  ASSERT_EQ(pile.num_outside, 0);
  const std::vector<int> types(12, 0);
  const PileResult again = simulator.Resettle(types, pile.world_from_object);
  EXPECT_TRUE(again.settled);
  EXPECT_EQ(again.num_outside, 0);
  EXPECT_LT(again.max_penetration_mm, 0.5);
  // at once: about the landing window (0.25 s) and the settle window (2 s); 2.74 s when this
  // was written, against the cap of 10 s
  EXPECT_LT(again.simulated_s, 3.0);
  ASSERT_EQ(again.world_from_object.size(), 12u);
  std::vector<double> moves_mm;
  for (size_t i = 0; i < 12; ++i) {
    const double moved_mm =
        (again.world_from_object[i].translation() - pile.world_from_object[i].translation()).norm();
    moves_mm.push_back(moved_mm);
  }
  // put back into a fresh world, without the contacts' friction anchors and impulses, the pile
  // takes its load again: it shifts about 0.2 mm, one part 1.1 mm (when this was written)
  std::sort(moves_mm.begin(), moves_mm.end());
  EXPECT_LT(moves_mm[6], 0.5);
  EXPECT_LT(moves_mm.back(), 2.0);
  const PileResult third = simulator.Resettle(types, pile.world_from_object);
  for (size_t i = 0; i < 12; ++i) {
    EXPECT_TRUE(third.world_from_object[i].matrix() == again.world_from_object[i].matrix());
  }
  EXPECT_THROW(simulator.Resettle({0}, {}), std::invalid_argument);
}

// Picking a part from under another lets the one on top fall: a plate resting on two blocks
// drops to the floor once a block is taken away, and the rest settles.
TEST_F(PileTest, ResettleAfterAPickLetsTheRestFall) {
  const PileSimulator simulator(BoxMesh({-20, -20, -5}, {20, 20, 5}), {}, PartPhysics{}, kBin,
                                SimulationParams{}, (dir_ / "cache").string());
  // two 40 x 40 x 10 mm plates side by side on the floor and one across them, 10 mm up
  const auto at = [](double x, double z) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = Eigen::Vector3d(x, 0, z);
    return pose;
  };
  const PileResult stacked = simulator.Resettle({0, 0, 0}, {at(-25, 5), at(25, 5), at(0, 15)});
  ASSERT_TRUE(stacked.settled);
  EXPECT_NEAR(stacked.world_from_object[2].translation().z(), 15, 0.5);
  const PileResult picked = simulator.Resettle({0, 0}, {at(-25, 5), at(0, 15)});
  ASSERT_TRUE(picked.settled);
  EXPECT_EQ(picked.num_outside, 0);
  // the plate that lay across tipped over the edge of its one support: one side on the floor
  EXPECT_LT(picked.world_from_object[1].translation().z(), 14) << "plate still up";
  const double tilt_deg =
      std::acos(std::min(1.0, std::abs(picked.world_from_object[1].linear()(2, 2)))) * 180 / M_PI;
  EXPECT_GT(tilt_deg, 5);
}

// A robot takes the most visible part on top first: a plate lying half over another goes
// before a plate standing on edge (less area seen from above), and the covered plate last,
// though more of it is seen than of the standing one; a plate standing on top of another goes
// first although it shows less area; the order never depends on the indices.
TEST_F(PileTest, PickOrderTakesTheMostVisiblePartOnTopFirst) {
  const PileSimulator simulator(BoxMesh({-20, -20, -5}, {20, 20, 5}), {}, PartPhysics{}, kBin,
                                SimulationParams{}, (dir_ / "cache").string());
  const auto at = [](double x, double z, bool standing) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    if (standing) {
      pose.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
    }
    pose.translation() = Eigen::Vector3d(x, 0, z);
    return pose;
  };
  const Eigen::Isometry3d bottom = at(-40, 5, false);
  const Eigen::Isometry3d top = at(-20, 15, false);  // covers half of the bottom plate
  const Eigen::Isometry3d on_edge = at(60, 20, true);
  EXPECT_EQ(simulator.PickOrder({0, 0, 0}, {bottom, top, on_edge}), (std::vector<int>{1, 2, 0}));
  EXPECT_EQ(simulator.PickOrder({0, 0, 0}, {on_edge, bottom, top}), (std::vector<int>{2, 0, 1}));
  // 400 mm^2 seen of the standing plate against 1200 of the one under it
  EXPECT_EQ(simulator.PickOrder({0, 0}, {at(40, 5, false), at(40, 30, true)}),
            (std::vector<int>{1, 0}));
  EXPECT_TRUE(simulator.PickOrder({}, {}).empty());
  EXPECT_THROW(simulator.PickOrder({0, 0}, {top}), std::invalid_argument);
}

// How far each part of `published` moved and turned by `after`: whether more than 1 mm or 1
// degree, more than 5 mm or 10 degrees, and how far it sank, summed over the parts.
struct MovedOn {
  int over_1 = 0, over_5 = 0;
  double sank_mm = 0;
};
MovedOn Moved(const PileResult& published, const PileResult& after) {
  MovedOn moved;
  for (size_t i = 0; i < published.world_from_object.size(); ++i) {
    const Eigen::Isometry3d& a = published.world_from_object[i];
    const Eigen::Isometry3d& b = after.world_from_object[i];
    const double mm = (b.translation() - a.translation()).norm();
    const double deg = Eigen::AngleAxisd(b.linear() * a.linear().transpose()).angle() * 180 / M_PI;
    moved.over_1 += mm > 1 || deg > 1 ? 1 : 0;
    moved.over_5 += mm > 5 || deg > 10 ? 1 : 0;
    moved.sank_mm += a.translation().z() - b.translation().z();
  }
  return moved;
}

// Connector piles published by the default settle rule (0.1 mm and 0.1 degree over 2 s) are at
// rest: simulated on in the same world until every part moved less than 0.1 mm and 0.1 degree
// over 1 s (60 s at most), none of the 24 parts of 2 piles moves more than 1 mm or 1 degree, and
// the heaps do not sink. The landed rule (1 mm, 1 degree over 0.25 s) publishes a pile with a
// part that moves on (seed 3, the first of seeds 1 to 24 that does): the check tells the rules
// apart, and with the landed rule as the default this test fails. stackgen-rest-check measures
// the rules over 300 piles (docs/results.md, "Piles at rest").
TEST_F(PileTest, DefaultSettleRulePublishesPilesThatStayPut) {
  const PileSimulator simulator = ConnectorSimulator();
  int piles = 0, parts = 0, over_1 = 0, at_rest = 0, tries = 0;
  double sank_mm = 0;
  for (uint64_t seed = 4; piles < 2 && tries < 10; ++seed, ++tries) {
    PileResult after;
    const PileResult pile =
        simulator.Simulate(std::vector<int>(12, 0), seed, kStrictRestRule, &after);
    if (!pile.settled || pile.num_outside > 0) continue;  // the generator redraws those
    if (piles == 0) {
      // going on changes nothing about what was published
      const PileResult alone = simulator.Simulate(12, seed);
      for (size_t i = 0; i < 12; ++i) {
        ASSERT_TRUE(alone.world_from_object[i].matrix() == pile.world_from_object[i].matrix());
      }
    }
    const MovedOn moved = Moved(pile, after);
    std::cout << "seed " << seed << ": settled after " << pile.simulated_s << " s; " << moved.over_1
              << " of 12 parts moved over 1 mm or 1 deg, sank " << moved.sank_mm / 12
              << " mm; at rest " << after.settled << " after " << after.simulated_s << " s\n";
    ++piles;
    parts += 12;
    over_1 += moved.over_1;
    sank_mm += moved.sank_mm;
    at_rest += after.settled ? 1 : 0;
  }
  ASSERT_EQ(piles, 2) << "in " << tries << " drops";
  EXPECT_EQ(over_1, 0);
  EXPECT_LT(std::abs(sank_mm / parts), 0.05);
  EXPECT_EQ(at_rest, 2);

  const PileSimulator loose(Connector(), ConnectorPieces(), PartPhysics{}, kBin,
                            testing::LandedRule(), (dir_ / "cache").string());
  uint64_t moved_seed = 0;
  for (uint64_t seed = 1; seed <= 24 && moved_seed == 0; ++seed) {
    PileResult loose_after;
    const PileResult loose_pile =
        loose.Simulate(std::vector<int>(12, 0), seed, kStrictRestRule, &loose_after);
    if (loose_pile.settled && loose_pile.num_outside == 0 &&
        Moved(loose_pile, loose_after).over_1 > 0) {
      moved_seed = seed;
    }
  }
  std::cout << "RULE_BEFORE_SEED " << moved_seed << "\n";
  EXPECT_GT(moved_seed, 0u) << "no pile of the rule before moved on";
}

// A flat 80 x 40 x 10 mm box dropped alone is published at rest: simulated on, at most one of 100
// moves more than 5 mm or 10 degrees, at most 2 more than 1 mm or 1 degree (with the holding
// friction throughout, seed 94: a box leaning on the wall, 35 mm up, slid 5 mm down it over
// 17 s; without friction anchors 3 boxes toppled after they were published, 8 moved more than
// 1 mm or 1 degree).
TEST_F(PileTest, PublishedFlatBoxesStayAtRest) {
  const PileSimulator simulator(BoxMesh({-40, -20, -5}, {40, 20, 5}), {}, PartPhysics{}, kBin,
                                SimulationParams{}, (dir_ / "cache").string());
  int over_1 = 0, over_5 = 0, at_rest = 0;
  for (uint64_t seed = 0; seed < 100; ++seed) {
    PileResult after;
    const PileResult pile = simulator.Simulate({0}, seed, kStrictRestRule, &after);
    ASSERT_TRUE(pile.settled) << "seed " << seed;
    const MovedOn moved = Moved(pile, after);
    over_1 += moved.over_1;
    over_5 += moved.over_5;
    at_rest += after.settled ? 1 : 0;
  }
  EXPECT_LE(over_5, 1);
  EXPECT_LE(over_1, 2);
  EXPECT_EQ(at_rest, 100);
}

// SimulationParams::free_friction_while_falling: 400 single flat 80 x 40 x 10 mm boxes (seeds
// 0..399) end on a large face more often with free friction while they fall (343 against 309
// with holding friction throughout, when this was written), and are published at rest all the
// same: simulated on, at most one moves more than 1 mm or 1 degree (1 when this was written).
TEST_F(PileTest, FreeFrictionWhileFallingLaysFlatBoxesFlat) {
  SimulationParams holding_params;
  holding_params.free_friction_while_falling = false;
  const TriangleMesh box = BoxMesh({-40, -20, -5}, {40, 20, 5});
  const std::string cache = (dir_ / "cache").string();
  const PileSimulator holding(box, {}, PartPhysics{}, kBin, holding_params, cache);
  const PileSimulator free(box, {}, PartPhysics{}, kBin, SimulationParams{}, cache);
  // the box's 10 mm axis nearest the vertical: it lies on an 80 x 40 face
  const auto flat = [](const PileResult& pile) {
    const Eigen::Matrix3d r = pile.world_from_object.at(0).linear();
    return std::abs(r(2, 2)) > std::max(std::abs(r(2, 0)), std::abs(r(2, 1)));
  };
  int flat_holding = 0, flat_free = 0, over_1 = 0;
  for (uint64_t seed = 0; seed < 400; ++seed) {
    flat_holding += flat(holding.Simulate(1, seed)) ? 1 : 0;
    PileResult after;
    const PileResult pile = free.Simulate({0}, seed, kStrictRestRule, &after);
    ASSERT_TRUE(pile.settled) << "seed " << seed;
    flat_free += flat(pile) ? 1 : 0;
    over_1 += Moved(pile, after).over_1;
  }
  std::cout << "flat: " << flat_free << " of 400 with free friction while falling, " << flat_holding
            << " with holding friction\n";
  EXPECT_GE(flat_free, flat_holding + 20);
  EXPECT_GE(flat_free, 336);  // 84 %
  EXPECT_LE(over_1, 1);
}

// SimulationParams::solver_iterations is the contact solver's: the default 20 and 10 drop the
// same parts to other poses (the same seed, a pile of 12 connectors; a falling pile gets at
// most 20 iterations, so the test is below that).
TEST_F(PileTest, SolverIterationsReachTheSolver) {
  SimulationParams twenty;
  twenty.solver_iterations = 10;
  const PileSimulator fewer(Connector(), ConnectorPieces(), PartPhysics{}, kBin, twenty,
                            (dir_ / "cache").string());
  const PileResult a = ConnectorSimulator().Simulate(12, 1);
  const PileResult b = fewer.Simulate(12, 1);
  ASSERT_EQ(a.world_from_object.size(), b.world_from_object.size());
  double largest_mm = 0;
  for (size_t i = 0; i < a.world_from_object.size(); ++i) {
    largest_mm = std::max(
        largest_mm,
        (a.world_from_object[i].translation() - b.world_from_object[i].translation()).norm());
  }
  EXPECT_GT(largest_mm, 1.0);
}

// A connector is a compound of nine convex pieces, and a vertical ray meets several of them (the
// gusset, then the plate under it): a part's own pieces must not count as covering it. Connector
// A lies on the floor with B above a third of it; C lies on its side, free, showing less area
// than what is still seen of A. B and C are on top; A goes last, though more of it is seen than
// of C.
TEST_F(PileTest, PickOrderCountsACompoundPartOnceAlongARay) {
  const PileSimulator simulator = ConnectorSimulator();
  const auto at = [](double x, double z, const Eigen::Matrix3d& turn) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = turn;
    pose.translation() = Eigen::Vector3d(x, 0, z);
    return pose;
  };
  const Eigen::Matrix3d flat = Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d on_side =
      Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Isometry3d a = at(-40, 0, flat);  // x -67.5..-12.5, upright up to z 55
  const Eigen::Isometry3d b = at(-5, 60, flat);  // x -32.5..22.5, above A's upright
  const Eigen::Isometry3d c = at(60, 27.5, on_side);
  EXPECT_EQ(simulator.PickOrder({0, 0, 0}, {a, b, c}), (std::vector<int>{1, 2, 0}));
  EXPECT_EQ(simulator.PickOrder({0, 0, 0}, {c, a, b}), (std::vector<int>{2, 0, 1}));
  // alone, each is on top, and the one showing more area goes first
  EXPECT_EQ(simulator.PickOrder({0, 0}, {c, a}), (std::vector<int>{1, 0}));
}

}  // namespace
}  // namespace stackgen
