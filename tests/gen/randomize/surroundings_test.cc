// The surroundings of a scene (gen/randomize/surroundings.h): what each probability does, and a
// fixed number of draws whatever the settings.
#include "gen/randomize/surroundings.h"

#include <random>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

// every probability 0: the bin as configured, no floor; 16 draws all the same
TEST(SurroundingsTest, NothingDrawnAtZero) {
  std::mt19937_64 engine(7), reference(7);
  const DrawnSurroundings drawn = SampleSurroundings(config::SurroundingsConfig(), engine);
  EXPECT_FALSE(drawn.bin_restyled);
  EXPECT_FALSE(drawn.bin_scuffed);
  EXPECT_EQ(drawn.floor, DrawnSurroundings::Floor::kNone);
  reference.discard(16);
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
