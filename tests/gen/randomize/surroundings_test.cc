// The surroundings of a scene (gen/randomize/surroundings.h): what each probability does, and a
// fixed number of draws whatever the settings.
#include "gen/randomize/surroundings.h"

#include <random>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

// every probability 0: the bin as configured, no floor; 24 draws all the same
TEST(SurroundingsTest, NothingDrawnAtZero) {
  std::mt19937_64 engine(7), reference(7);
  const DrawnSurroundings drawn = SampleSurroundings(config::SurroundingsConfig(), engine);
  EXPECT_FALSE(drawn.bin_restyled);
  EXPECT_FALSE(drawn.bin_scuffed);
  EXPECT_EQ(drawn.floor, DrawnSurroundings::Floor::kNone);
  reference.discard(24);
  EXPECT_EQ(engine(), reference());
}

// probability 1 always happens, in every scene; the metal bin wins over the colour; a table or a
// belt as conveyor_fraction says; values in their documented ranges
TEST(SurroundingsTest, ProbabilityOneAlwaysHappens) {
  config::SurroundingsConfig metal;
  metal.set_metal_bin_probability(1);
  metal.set_bin_color_probability(1);
  metal.set_table_probability(1);
  metal.set_conveyor_fraction(1);
  config::SurroundingsConfig coloured;
  coloured.set_bin_color_probability(1);
  coloured.set_bin_roughness_min(0.5);
  coloured.set_bin_roughness_max(0.6);
  coloured.set_scuffed_bin_probability(1);
  coloured.set_table_probability(1);
  coloured.set_conveyor_fraction(0);
  std::mt19937_64 engine(3);
  for (int scene = 0; scene < 100; ++scene) {
    const DrawnSurroundings a = SampleSurroundings(metal, engine);
    EXPECT_TRUE(a.bin_restyled);
    EXPECT_EQ(a.bin_metallic, 1.f);
    EXPECT_GE(a.bin_roughness, 0.2f);
    EXPECT_LE(a.bin_roughness, 0.6f);
    EXPECT_EQ(a.floor, DrawnSurroundings::Floor::kConveyor);
    EXPECT_LE(a.floor_color.maxCoeff(), 0.15f);
    const DrawnSurroundings b = SampleSurroundings(coloured, engine);
    EXPECT_TRUE(b.bin_restyled);
    EXPECT_EQ(b.bin_metallic, 0.f);
    EXPECT_GE(b.bin_roughness, 0.5f);
    EXPECT_LE(b.bin_roughness, 0.6f);
    EXPECT_TRUE(b.bin_scuffed);
    EXPECT_GE(b.bin_scuff_strength, 0.2f);
    EXPECT_EQ(b.floor, DrawnSurroundings::Floor::kTable);
  }
}

// the tote's saturation and value ranges reach white, grey and black; a table's finish: steel,
// wood or paint as the fractions say, painted grey when table_saturation_max is 0 (as before)
TEST(SurroundingsTest, TotesAndTablesOfEveryKind) {
  config::SurroundingsConfig wide;
  wide.set_bin_color_probability(1);
  wide.set_bin_saturation_min(0);
  wide.set_bin_saturation_max(0.05);
  wide.set_bin_value_min(0.9);
  wide.set_bin_value_max(0.95);
  wide.set_table_probability(1);
  wide.set_conveyor_fraction(0);
  wide.set_metal_table_fraction(0.3);
  wide.set_wood_table_fraction(0.3);
  wide.set_table_saturation_max(0.6);
  std::mt19937_64 engine(5);
  int metal = 0, wood = 0, painted = 0, coloured = 0;
  for (int scene = 0; scene < 400; ++scene) {
    const DrawnSurroundings a = SampleSurroundings(wide, engine);
    // a white tote
    ASSERT_GE(a.bin_color.minCoeff(), 0.9f * 0.95f - 1e-6f);
    ASSERT_LE(a.bin_color.maxCoeff() - a.bin_color.minCoeff(), 0.05f * 0.95f + 1e-6f);
    ASSERT_EQ(a.floor, DrawnSurroundings::Floor::kTable);
    switch (a.floor_finish) {
      case DrawnSurroundings::Finish::kMetal:
        ++metal;
        ASSERT_EQ(a.floor_metallic, 1.f);
        ASSERT_LE(a.floor_roughness, 0.5f);
        break;
      case DrawnSurroundings::Finish::kWood:
        ++wood;
        ASSERT_EQ(a.floor_metallic, 0.f);
        // a brown: red over green over blue
        ASSERT_GT(a.floor_color.x(), a.floor_color.y());
        ASSERT_GT(a.floor_color.y(), a.floor_color.z());
        break;
      case DrawnSurroundings::Finish::kPainted:
        ++painted;
        coloured += a.floor_color.maxCoeff() - a.floor_color.minCoeff() > 0.2f;
        break;
    }
  }
  // 30 %, 30 % and 40 % of 400, within four standard deviations
  EXPECT_NEAR(metal, 120, 37);
  EXPECT_NEAR(wood, 120, 37);
  EXPECT_NEAR(painted, 160, 40);
  EXPECT_GT(coloured, 20);

  // the defaults paint every table grey, tinted at most 5 %
  config::SurroundingsConfig grey;
  grey.set_table_probability(1);
  grey.set_conveyor_fraction(0);
  for (int scene = 0; scene < 100; ++scene) {
    const DrawnSurroundings a = SampleSurroundings(grey, engine);
    ASSERT_EQ(a.floor_finish, DrawnSurroundings::Finish::kPainted);
    ASSERT_NEAR(a.floor_color.x() / a.floor_color.y(), 1.0, 0.051);
    ASSERT_NEAR(a.floor_color.z() / a.floor_color.y(), 1.0, 0.051);
    ASSERT_GE(a.floor_color.y(), 0.1f - 1e-6f);
    ASSERT_LE(a.floor_color.y(), 0.7f + 1e-6f);
  }
}

// the hexcone model at its corners and in between
TEST(SurroundingsTest, RgbOfHsv) {
  EXPECT_TRUE(RgbOfHsv(0, 1, 1).isApprox(Eigen::Vector3f(1, 0, 0)));
  EXPECT_TRUE(RgbOfHsv(120, 1, 1).isApprox(Eigen::Vector3f(0, 1, 0)));
  EXPECT_TRUE(RgbOfHsv(240, 0.5, 0.8).isApprox(Eigen::Vector3f(0.4f, 0.4f, 0.8f)));
  EXPECT_TRUE(RgbOfHsv(420, 1, 1).isApprox(RgbOfHsv(60, 1, 1)));
  EXPECT_TRUE(RgbOfHsv(60, 1, 1).isApprox(Eigen::Vector3f(1, 1, 0)));
}

}  // namespace
}  // namespace stackgen
