// Tests of the drop modes, several part types, rolling friction and tote meshes of PileSimulator.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "gen/mesh/mesh.h"
#include "gen/physics/pile.h"
#include "tests/support/meshes.h"
#include "tests/support/physics.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using testing::BoxMesh;
using testing::ModelPath;

const BinSpec kBin{200, 150, 100, 8, 0.6, 0.1, {}};

class PileModesTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("stackgen-pile-modes"); }
  void TearDown() override { fs::remove_all(dir_); }

  static PartType Connector() {
    static const PartType type{LoadMesh(ModelPath("corner_connector.obj"), 1.0),
                               LoadMeshPieces(ModelPath("corner_connector_collision.obj"), 1.0),
                               PartPhysics{}, ""};
    return type;
  }
  static PartType Pin(double rolling_friction_mm) {
    PartType type{LoadMesh(ModelPath("dowel_pin.obj"), 1.0), {}, PartPhysics{}, ""};
    type.physics.density_kg_m3 = 7850;
    type.physics.rolling_friction_mm = rolling_friction_mm;
    return type;
  }
  std::string Cache() const { return dir_ + "/cache"; }

  std::string dir_;
};

// mean horizontal distance of the parts' mesh origins from (x, y), mm
double MeanDistanceFrom(const PileResult& pile, const Eigen::Vector2d& point) {
  double sum = 0;
  for (const auto& pose : pile.world_from_object) {
    sum += (pose.translation().head<2>() - point).norm();
  }
  return sum / pile.world_from_object.size();
}

// Two part types in one pile: each object gets its own type's shape, mass and hull faces, and
// the pile settles inside the bin.
TEST_F(PileModesTest, SeveralPartTypesInOnePile) {
  const PileSimulator simulator(
      {Connector(), PartType{BoxMesh({30, 20, 10}), {}, PartPhysics{}, ""}}, kBin,
      SimulationParams{}, Cache());
  EXPECT_NEAR(simulator.mass_kg(0), 0.0959, 0.001);
  EXPECT_NEAR(simulator.mass_kg(1), 30 * 20 * 10 * 2700e-9, 1e-9);
  EXPECT_EQ(simulator.hull_faces(1).size(), 6u);
  EXPECT_GT(simulator.hull_faces(0).size(), 6u);
  EXPECT_NE(simulator.CollisionDescription(1).find("convex hull"), std::string::npos);
  const std::vector<int> types = {0, 1, 1, 0, 1, 0, 0, 1};
  const PileResult pile = simulator.Simulate(types, 5);
  ASSERT_EQ(pile.world_from_object.size(), types.size());
  EXPECT_TRUE(pile.settled);
  EXPECT_EQ(pile.num_outside, 0);
  EXPECT_LT(pile.max_penetration_mm, 0.5);
  // a box rests flat on one of its faces or on another part: its centre is at least 5 mm up
  for (size_t i = 0; i < types.size(); ++i) {
    if (types[i] == 1) {
      EXPECT_GE(pile.world_from_object[i].translation().z(), 5 - 0.5) << i;
    }
  }
  EXPECT_THROW(simulator.Simulate({0, 2}, 1), std::runtime_error);
  EXPECT_THROW(PileSimulator({}, kBin, SimulationParams{}, Cache()), std::runtime_error);
}

// Sequential drops from a fixed point heap the parts around that point; random-volume drops
// spread them over the floor. Both settle inside the bin, without interpenetration (by the rule
// before piles had to be at rest: the drop modes are what is tested).
TEST_F(PileModesTest, SequentialDropsHeapAroundTheDropPoint) {
  SimulationParams sequential = testing::LandedRule();
  sequential.drop_mode = DropMode::kSequential;
  sequential.drop_point_mm = Eigen::Vector2d(-70, 40);
  const BinSpec wide{300, 240, 100, 8, 0.6, 0.1, {}};
  const PileSimulator heap({Connector()}, wide, sequential, Cache());
  const PileSimulator rain({Connector()}, wide, testing::LandedRule(), Cache());
  double heap_distance = 0, rain_distance = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    const PileResult a = heap.Simulate(8, seed);
    const PileResult b = rain.Simulate(8, seed);
    for (const PileResult* pile : {&a, &b}) {
      EXPECT_TRUE(pile->settled) << seed;
      EXPECT_EQ(pile->num_outside, 0) << seed;
      EXPECT_LT(pile->max_penetration_mm, 0.5) << seed;
    }
    heap_distance += MeanDistanceFrom(a, sequential.drop_point_mm) / 4;
    rain_distance += MeanDistanceFrom(b, sequential.drop_point_mm) / 4;
    // one by one: the sequential pile takes longer to build than the waves
    EXPECT_GT(a.simulated_s, b.simulated_s) << seed;
  }
  std::printf("mean distance from the drop point: sequential %.1f mm, random volume %.1f mm\n",
              heap_distance, rain_distance);
  EXPECT_LT(heap_distance, 0.6 * rain_distance)
      << "sequential " << heap_distance << " mm, random volume " << rain_distance << " mm";
}

// Rolling friction stops round parts sooner: dowel pins settle in less simulated time with it.
TEST_F(PileModesTest, RollingFrictionSettlesRoundPartsSooner) {
  const PileSimulator smooth({Pin(0)}, kBin, SimulationParams{}, Cache());
  const PileSimulator resisting({Pin(1.0)}, kBin, SimulationParams{}, Cache());
  double smooth_s = 0, resisting_s = 0;
  for (uint64_t seed = 1; seed <= 8; ++seed) {
    const PileResult a = smooth.Simulate(4, seed);
    const PileResult b = resisting.Simulate(4, seed);
    EXPECT_TRUE(b.settled) << seed;
    smooth_s += a.simulated_s;
    resisting_s += b.simulated_s;
  }
  std::printf("settling time of 8 piles of 4 pins: %.2f s with rolling friction, %.2f s without\n",
              resisting_s, smooth_s);
  EXPECT_LT(resisting_s, smooth_s) << "with " << resisting_s << " s, without " << smooth_s << " s";
}

// A tote given as a triangle mesh (thin walls, no boxes) holds a settled pile like the box bin,
// with the landed rule (1 mm, 1 degree over 0.25 s: a falling pile has landed). A thin triangle
// floor is not a box: a tote keeps the holding friction throughout, and the drop of seed 1 loses
// a part through the floor (the generator redraws such drops; docs/configuration.md, "Piles:
// parts, distractors, drops and checks"); seeds 2 to 4 stay inside.
TEST_F(PileModesTest, ToteMeshHoldsThePile) {
  BinSpec tote = kBin;
  tote.mesh = MakeOpenBinMesh(kBin.inner_length_mm, kBin.inner_width_mm, kBin.inner_height_mm,
                              kBin.wall_mm);
  const PileSimulator simulator({Connector()}, tote, testing::LandedRule(), Cache());
  for (uint64_t seed : {2u, 3u, 4u}) {
    const PileResult pile = simulator.Simulate(12, seed);
    EXPECT_TRUE(pile.settled) << seed;
    EXPECT_EQ(pile.num_outside, 0) << seed;
    EXPECT_LT(pile.max_penetration_mm, 0.5) << seed;
    for (const auto& pose : pile.world_from_object) {
      EXPECT_GT(pose.translation().z(), -1.0) << seed;  // nothing fell through the floor
    }
  }
}

}  // namespace
}  // namespace stackgen
