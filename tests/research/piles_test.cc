#include "research/stats/piles.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "research/stats/statistics.h"

namespace stackgen::stats {
namespace {

constexpr int kPairs = 100;
constexpr int kScenes = 40;
constexpr int kParts = 12;

// `scenes` piles of kParts parts from one model in which the parts of a pile share a lot: a
// pile height, a tilt, a favourite face and a side of the bin, drawn per scene (as a real pile
// shares its fill level and the way it slid). `lift_mm` raises every part.
Dataset MakePiles(std::mt19937_64* engine, int scenes, double lift_mm) {
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(-180.0, 180.0);
  std::uniform_int_distribution<int> face(0, 5);
  Dataset dataset;
  dataset.path = "piles";
  dataset.scenes = scenes;
  for (int s = 0; s < scenes; ++s) {
    const double pile_mm = 40.0 + 10.0 * normal(*engine);
    const double tilt_deg = 20.0 * normal(*engine);
    const double side_mm = 25.0 * normal(*engine);
    const int favourite = face(*engine);
    for (int k = 0; k < kParts; ++k) {
      PostureSample sample;
      sample.class_name = "part";
      sample.scene = s;
      sample.pile = s;
      sample.alpha_deg = uniform(*engine);
      sample.beta_deg = std::clamp(tilt_deg + 10.0 * normal(*engine), -90.0, 90.0);
      sample.gamma_deg = std::remainder(tilt_deg * 3.0 + 30.0 * normal(*engine), 360.0);
      sample.heading_deg = uniform(*engine);
      sample.resting_face = k % 2 == 0 ? favourite : face(*engine);
      sample.world_position_mm =
          Eigen::Vector3d(side_mm + 20.0 * normal(*engine), 10.0 * normal(*engine),
                          pile_mm + lift_mm + 3.0 * normal(*engine));
      dataset.samples.push_back(sample);
    }
  }
  return dataset;
}

// the heights of a dataset's parts
std::vector<double> Heights(const Dataset& dataset) {
  std::vector<double> heights;
  for (const PostureSample& sample : dataset.samples)
    heights.push_back(sample.world_position_mm.z());
  return heights;
}

// Holm's adjustment against values worked by hand (R's p.adjust(method = "holm") agrees)
TEST(PilesTest, HolmAdjustment) {
  const std::vector<double> adjusted = HolmAdjust({0.01, 0.04, 0.03, 0.005});
  const std::vector<double> expected = {0.03, 0.06, 0.06, 0.02};
  ASSERT_EQ(adjusted.size(), expected.size());
  for (size_t k = 0; k < expected.size(); ++k) EXPECT_NEAR(adjusted[k], expected[k], 1e-15) << k;
  EXPECT_EQ(HolmAdjust({0.5, 0.9}), (std::vector<double>{1.0, 1.0}));
  EXPECT_THROW(HolmAdjust({0.5, 1.5}), std::invalid_argument);
}

// two datasets of one model: the pile tests say "different" at most at the stated rate, where
// a test that counts the parts as independent (the KS test on the heights alone) cries wolf
// most of the time
TEST(PilesTest, SameModelFalseAlarmsAtMostTheStatedRate) {
  std::mt19937_64 engine(2026);
  PileOptions options;
  options.permutations = 199;
  int different = 0, naive_different = 0;
  for (int pair = 0; pair < kPairs; ++pair) {
    const Dataset a = MakePiles(&engine, kScenes, 0.0);
    const Dataset b = MakePiles(&engine, kScenes, 0.0);
    options.seed = pair;
    const PileComparison comparison = ComparePiles(a, b, options);
    ASSERT_EQ(comparison.tests.size(), 7u);
    different += comparison.different ? 1 : 0;
    naive_different += KolmogorovSmirnov2(Heights(a), Heights(b)).p < 0.05 ? 1 : 0;
  }
  // 5 expected at 0.05; 10 or more happens by chance with probability 0.03
  EXPECT_LE(different, 9);
  EXPECT_GE(naive_different, 50);
}

// the same model with every part 12 mm higher (the size of the friction 1.5 effect on the
// default config's piles): found nearly always, by the height test
TEST(PilesTest, HigherPilesAreDifferent) {
  std::mt19937_64 engine(7);
  PileOptions options;
  options.permutations = 199;
  int different = 0, height_different = 0;
  for (int pair = 0; pair < kPairs; ++pair) {
    const PileComparison comparison =
        ComparePiles(MakePiles(&engine, kScenes, 0.0), MakePiles(&engine, kScenes, 12.0), options);
    different += comparison.different ? 1 : 0;
    height_different += comparison.tests[5].name == "height" && comparison.tests[5].different;
  }
  EXPECT_GE(different, 90);
  EXPECT_GE(height_different, 90);
}

// the same datasets and seed give the same p-values; a dataset against itself gives p = 1
TEST(PilesTest, DeterministicAndSelfSame) {
  std::mt19937_64 engine(3);
  const Dataset a = MakePiles(&engine, 12, 0.0);
  const Dataset b = MakePiles(&engine, 12, 0.0);
  PileOptions options;
  const PileComparison first = ComparePiles(a, b, options);
  const PileComparison again = ComparePiles(a, b, options);
  for (size_t k = 0; k < first.tests.size(); ++k) {
    EXPECT_EQ(first.tests[k].p, again.tests[k].p) << first.tests[k].name;
    EXPECT_EQ(first.tests[k].value, again.tests[k].value) << first.tests[k].name;
  }
  const PileComparison self = ComparePiles(a, a, options);
  for (const PileTest& test : self.tests) {
    EXPECT_EQ(test.value, 0.0) << test.name;
    EXPECT_EQ(test.p, 1.0) << test.name;
  }
  EXPECT_FALSE(self.different);
  EXPECT_EQ(self.piles_a, 12);
  EXPECT_EQ(self.piles_b, 12);
}

// parts without positions (a COCO file without world_t_m2w) leave height and radius out; a
// split keeps every sample in one half by its scene
TEST(PilesTest, LeftOutMeasuresAndSplits) {
  std::mt19937_64 engine(5);
  Dataset a = MakePiles(&engine, 10, 0.0);
  const Dataset b = MakePiles(&engine, 10, 0.0);
  for (PostureSample& sample : a.samples) sample.world_position_mm.setConstant(std::nan(""));
  const PileComparison comparison = ComparePiles(a, b, PileOptions{});
  EXPECT_EQ(comparison.tests.size(), 5u);
  ASSERT_EQ(comparison.left_out.size(), 2u);
  EXPECT_EQ(comparison.left_out[0], "height: A does not give it");

  std::vector<bool> first(10, false);
  first[2] = first[7] = true;
  const auto [one, other] = SplitScenes(b, first);
  EXPECT_EQ(one.scenes, 2);
  EXPECT_EQ(other.scenes, 8);
  EXPECT_EQ(one.samples.size(), 2u * kParts);
  EXPECT_EQ(other.samples.size(), 8u * kParts);
  for (const PostureSample& sample : one.samples)
    EXPECT_TRUE(sample.scene == 2 || sample.scene == 7);
  EXPECT_THROW(SplitScenes(b, std::vector<bool>(9, true)), std::invalid_argument);
}

}  // namespace
}  // namespace stackgen::stats
