// PileSimulator::Lift (gen/physics/pile.cc): a suction cup or jaws lifting a part in the pile's
// own world. A lone bar lifted at its middle comes out, level; held off its centre it swings; a
// bar pinned under two steel blocks stays in the pile when the cup cannot hold their weight, and
// the record says which parts moved; jaws lift it across its width, and let go when they
// squeeze too little.
#include <gtest/gtest.h>

#include <vector>

#include "gen/physics/pile.h"
#include "tests/support/meshes.h"

namespace stackgen {
namespace {

const BinSpec kBin{200, 150, 100, 8, 0.6, 0.1, {}};

Eigen::Isometry3d At(double x, double y, double z) {
  return Eigen::Isometry3d(Eigen::Translation3d(x, y, z));
}

// type 0: an aluminium bar 100 x 20 x 10 mm (54 g); type 1: a steel block 40 x 40 x 20 mm (250 g)
PileSimulator BarAndBlocks() {
  PartType bar;
  bar.mesh = testing::BoxMesh(Eigen::Vector3f(100, 20, 10));
  bar.physics.density_kg_m3 = 2700;
  bar.collision_pieces = {bar.mesh};
  PartType block;
  block.mesh = testing::BoxMesh(Eigen::Vector3f(40, 40, 20));
  block.physics.density_kg_m3 = 7800;
  block.collision_pieces = {block.mesh};
  return PileSimulator({bar, block}, kBin, SimulationParams{}, "");
}

const Eigen::Vector3d kUp = Eigen::Vector3d::UnitZ();

// a lone bar lifted from the middle of its top face comes out, level, nothing else moves; held
// 40 mm off its middle it still comes out but swings until its centre hangs under the cup
TEST(LiftTest, LoneBarComesOut) {
  const PileSimulator simulator = BarAndBlocks();
  LiftParams lift;
  const LiftResult middle = simulator.Lift({0}, {At(0, 0, 5)}, 0, {0, 0, 10}, kUp, lift);
  EXPECT_EQ(middle.outcome, LiftResult::Outcome::kLifted);
  EXPECT_NEAR(middle.rise_mm, lift.lift_mm, 2);
  EXPECT_LT(middle.swing_deg, 2);
  ASSERT_EQ(middle.moved_mm.size(), 1u);
  EXPECT_EQ(middle.moved_mm[0], 0);

  const LiftResult end = simulator.Lift({0}, {At(0, 0, 5)}, 0, {40, 0, 10}, kUp, lift);
  EXPECT_EQ(end.outcome, LiftResult::Outcome::kLifted);
  EXPECT_GT(end.swing_deg, 30);
}

// the bar under two blocks lying on its ends: lifting it means lifting 0.55 kg, which a 15 mm
// cup at 10 kPa (1.8 N) cannot hold: the cup lets go in the pile. At 60 kPa (10.6 N) the bar
// rises with the blocks on it (until they slide off and it swings free or is let go): the
// record shows both blocks moved, and not the bar beside them
TEST(LiftTest, BarPinnedUnderTwoBlocksStaysAndTheBlocksMove) {
  const PileSimulator simulator = BarAndBlocks();
  const std::vector<int> types = {0, 1, 1, 0};
  const std::vector<Eigen::Isometry3d> poses = {At(0, 0, 5), At(-35, 0, 20), At(35, 0, 20),
                                                At(0, 50, 5)};
  LiftParams weak;
  weak.vacuum_kpa = 10;
  const LiftResult stuck = simulator.Lift(types, poses, 0, {0, 0, 10}, kUp, weak);
  EXPECT_EQ(stuck.outcome, LiftResult::Outcome::kStuck);
  EXPECT_LT(stuck.rise_mm, 2);

  const LiftResult strong = simulator.Lift(types, poses, 0, {0, 0, 10}, kUp, LiftParams{});
  EXPECT_NE(strong.outcome, LiftResult::Outcome::kStuck);
  EXPECT_GT(strong.rise_mm, 10);
  ASSERT_EQ(strong.moved_mm.size(), 4u);
  EXPECT_GT(strong.moved_mm[1], 10);
  EXPECT_GT(strong.moved_mm[2], 10);
  EXPECT_LT(strong.moved_mm[3], 1) << "the bar beside them";
}

// jaws closed across the bar's width (y) at its middle lift it level; at 40 mm from its middle
// it turns about the closing line until its centre hangs below; squeezed with 0.2 N a finger
// (0.2 N of friction against its 0.53 N) it stays
TEST(LiftTest, JawsLiftAcrossTheBar) {
  const PileSimulator simulator = BarAndBlocks();
  LiftParams jaws;
  jaws.hold = LiftParams::Hold::kJaws;
  jaws.jaw_axis = Eigen::Vector3d::UnitY();
  const LiftResult middle = simulator.Lift({0}, {At(0, 0, 5)}, 0, {0, 0, 5}, kUp, jaws);
  EXPECT_EQ(middle.outcome, LiftResult::Outcome::kLifted);
  EXPECT_NEAR(middle.rise_mm, jaws.lift_mm, 2);
  EXPECT_LT(middle.swing_deg, 2);
  const LiftResult end = simulator.Lift({0}, {At(0, 0, 5)}, 0, {40, 0, 5}, kUp, jaws);
  EXPECT_EQ(end.outcome, LiftResult::Outcome::kLifted);
  EXPECT_GT(end.swing_deg, 30);
  LiftParams weak = jaws;
  weak.jaw_grip_force_n = 0.2;
  EXPECT_EQ(simulator.Lift({0}, {At(0, 0, 5)}, 0, {0, 0, 5}, kUp, weak).outcome,
            LiftResult::Outcome::kStuck);
}

}  // namespace
}  // namespace stackgen
