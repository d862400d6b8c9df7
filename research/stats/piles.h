#pragma once

// Comparing the piles of two datasets. The parts of one pile lie on each other: their heights,
// faces and angles are not independent draws, so a test that counts parts as independent
// calls two seeds of one config "different" far more often than its significance says. Here
// every measure is tested by permuting whole piles between the two datasets (the pile is the
// independent draw: a scene, or the views of one pile, PostureSample::pile), and the family of
// tests is corrected with Holm's step-down method, so the verdict "different" comes from the
// pair of datasets at most at the stated rate when both come from one config.

#include <cstdint>
#include <string>
#include <vector>

#include "research/stats/dataset.h"

namespace stackgen::stats {

/// One measure's test.
struct PileTest {
  /// "alpha", "beta", "gamma" (posture angles, degrees), "heading" (the angle about the
  /// vertical), "face" (resting face), "height" (z of the part's origin above the bin floor,
  /// mm), "radius" (distance of the origin from the bin's vertical centre line, mm).
  std::string name;
  /// The statistic: "D" (two-sample Kolmogorov-Smirnov distance), "V" (Kuiper's, for the
  /// heading on its circle) or "chi2" (Pearson's homogeneity statistic of the face counts).
  std::string statistic;
  /// Its value between the two datasets.
  double value = 0.0;
  /// chi2 only: categories used - 1.
  int dof = 0;
  /// The permutation p-value: (1 + permutations with a statistic at least `value`) /
  /// (1 + permutations).
  double p = 1.0;
  /// p adjusted for the family of tests by Holm's method.
  double p_holm = 1.0;
  /// p_holm < significance.
  bool different = false;
  /// Values used in each dataset (parts with this measure known).
  int64_t n1 = 0;
  int64_t n2 = 0;
};

/// The comparison of two datasets' piles.
struct PileComparison {
  /// The tests run, in the order of PileTest::name above; a measure neither dataset knows
  /// (positions in a COCO file without world_t_m2w, faces) is left out.
  std::vector<PileTest> tests;
  /// The measures left out, and why ("height: A has no part positions").
  std::vector<std::string> left_out;
  /// Some test says "different" after the correction.
  bool different = false;
  /// Piles holding at least one part used, per dataset (the units permuted).
  int64_t piles_a = 0;
  int64_t piles_b = 0;
};

/// How to compare.
struct PileOptions {
  /// Random reassignments of whole piles to the two datasets, 19..1000000. Default 999: the
  /// smallest p-value is 1/1000.
  int permutations = 999;
  /// Seed of the engine that draws the permutations (the same seed, the same p-values).
  uint64_t seed = 1;
  /// Family-wise significance, 0 < significance < 1. Default 0.05.
  double significance = 0.05;
};

/// Compares the piles of `a` and `b` (see the file comment). Throws std::invalid_argument on
/// options out of range or a dataset without samples.
PileComparison ComparePiles(const Dataset& a, const Dataset& b, const PileOptions& options);

/// Holm's step-down adjustment of `p` (one p-value per test of a family): with the p-values
/// sorted ascending, p_(i) becomes max over j <= i of min(1, (m - j + 1) p_(j)). Rejecting the
/// tests whose adjusted value is below A keeps the chance of any false rejection at most A.
/// The result is in the order of `p`. Throws std::invalid_argument on a value outside [0, 1].
std::vector<double> HolmAdjust(const std::vector<double>& p);

/// The samples of `dataset` split by scene: those of the scenes s with `first[s]` true, and the
/// others; scene numbers are kept. `first` holds one flag per scene of the dataset.
std::pair<Dataset, Dataset> SplitScenes(const Dataset& dataset, const std::vector<bool>& first);

}  // namespace stackgen::stats
