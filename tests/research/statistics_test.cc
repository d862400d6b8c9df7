// The two-sample tests of research/stats/statistics.h against known values.
//
// Reference values come from scipy 1.10.1 (Debian python3-scipy), used once to make the constants
// below; neither the build nor the tests need it. The samples are literals, drawn and rounded by
// this snippet, so scipy and these tests see the same numbers:
//
//   import random, numpy as np
//   from scipy import stats, special
//   r = random.Random(2021)
//   a = [round(r.gauss(0.0, 1.0), 3) for _ in range(12)]
//   b = [round(r.gauss(1.0, 1.0), 3) for _ in range(15)]
//   c = [round(r.gauss(0.0, 1.0), 3) for _ in range(20)]
//   d = [round(r.gauss(0.8, 1.5), 3) for _ in range(20)]
//   e = [round(r.gauss(0.0, 1.0), 2) for _ in range(150)]
//   f = [round(r.gauss(0.4, 1.0), 2) for _ in range(120)]
//   stats.ks_2samp(a, b, method='exact')      # D, p of KsExactUnequalSizes
//   stats.ks_2samp(c, d, method='exact')      # D, p of KsExactEqualSizes
//   D = stats.ks_2samp(e, f).statistic        # KsAsymptotic
//   special.kolmogorov(D * np.sqrt(150 * 120 / 270))
//   stats.ks_2samp([0, 0, 1, 1, 1, 2, 2, 3], [0, 1, 1, 2, 2, 2, 3, 3, 3, 3], method='exact')
//   stats.ks_2samp(list(range(50)), [100 + v for v in range(40)], method='exact')
//   special.kolmogorov(lam); stats.chi2.sf(x, k)
//   stats.chisquare([18, 25, 30, 27], [100 * q for q in [0.2, 0.3, 0.3, 0.2]])
//   stats.chi2_contingency([[40, 25, 20, 15], [30, 35, 10, 25]], correction=False)

#include "research/stats/statistics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

namespace stackgen::stats {
namespace {

const std::vector<double> kA = {1.021,  -1.693, -0.725, -0.206, -1.783, -2.023,
                                -0.358, 0.059,  -0.142, 1.126,  0.507,  -0.308};
const std::vector<double> kB = {1.79,  -0.447, 0.419, -0.118, 2.777, 1.59,  0.347, 1.136,
                                1.928, 0.451,  2.892, 0.98,   0.829, 1.891, 0.3};
const std::vector<double> kC = {0.719,  0.536, 0.458,  1.075,  -0.115, 0.934,  0.831,
                                -0.794, 0.185, 0.065,  0.075,  -2.024, -0.474, 0.208,
                                0.575,  0.378, -0.939, -0.836, -0.469, 0.146};
const std::vector<double> kD = {0.352,  1.625, 1.231, -1.197, -0.382, -1.06, -0.208,
                                2.172,  0.171, 0.688, 1.731,  -1.061, 1.721, -0.404,
                                -2.412, 0.973, 0.94,  1.951,  0.306,  0.397};
// 150 and 120 values rounded to 0.01: ties within and between the samples
const std::vector<double> kE = {
    -0.29, 0.99,  -0.4,  -1.38, -0.81, 0.81,  0.59,  0.18,  -0.66, 0.22,  0.12,  -0.06, -1.25,
    1.6,   0.48,  -0.25, 1.58,  1.3,   0.21,  -0.24, -0.58, 0.25,  -0.12, -0.23, 0.13,  -2.05,
    1.51,  -0.46, 0.58,  -0.98, -0.7,  -0.88, 1.53,  -1.04, -0.65, 0.43,  0.77,  0.12,  0.21,
    -0.57, 0.03,  -0.69, 0.18,  -0.79, -0.99, -0.3,  -0.11, 0.63,  -0.11, -0.32, 1.54,  0.05,
    0.16,  -0.06, 0.35,  -0.34, 0.22,  0.59,  1.04,  1.61,  0.63,  0.4,   -1.55, 0.31,  -0.38,
    0.55,  -0.17, -0.24, 0.43,  1.13,  -1.2,  0.05,  -1.5,  -0.27, -1.2,  -0.54, -0.98, 0.8,
    -0.13, -1.6,  1.15,  -1.34, 0.63,  -1.8,  -0.32, -0.16, -0.04, 0.68,  0.76,  -0.63, -2.39,
    -0.53, 0.59,  0.27,  1.93,  -0.04, -1.29, -1.24, 1.22,  -0.01, -1.69, 0.08,  1.2,   -0.15,
    -2.17, -1.27, 0.39,  0.14,  -0.4,  1.17,  1.19,  -0.25, 1.82,  -0.59, -1.14, 0.14,  -1.02,
    0.37,  -1.69, -0.99, -0.64, 0.17,  -2.01, 0.48,  -0.25, 1.92,  -0.05, -0.83, 1.56,  0.22,
    0.89,  -0.24, -2.92, 0.87,  0.88,  0.44,  1.46,  0.19,  -0.54, -1.1,  0.22,  0.45,  -1.86,
    1.34,  1.54,  0.13,  -1.14, 0.05,  -0.1,  -2.38};
const std::vector<double> kF = {
    1.31,  -0.59, 0.39,  -0.52, 1.44,  -1.07, -1.73, -0.53, -1.77, 1.5,   3.42,  1.67,
    -0.82, -0.41, 1.53,  -0.02, 1.13,  2.02,  0.35,  1.0,   -0.2,  0.56,  -0.26, -0.89,
    0.96,  -1.43, 0.26,  -1.58, 0.36,  -1.56, 1.03,  1.26,  -0.7,  -0.8,  0.42,  1.77,
    2.03,  0.62,  0.15,  -0.04, -0.28, -0.28, 1.88,  -0.12, -0.3,  1.24,  1.47,  0.36,
    0.11,  0.25,  -1.73, 0.3,   1.47,  0.09,  0.21,  1.3,   0.67,  -0.4,  -1.16, 0.89,
    1.66,  1.22,  -0.9,  3.08,  -0.39, 1.87,  -0.39, 0.14,  -1.78, 0.35,  2.77,  0.7,
    1.58,  0.8,   1.7,   1.24,  -0.44, 1.35,  1.08,  0.0,   0.67,  -0.05, 1.43,  2.22,
    -0.57, -0.17, 1.72,  0.58,  -1.27, 1.75,  -0.07, 0.77,  -0.79, -0.33, -0.32, -0.09,
    1.24,  0.66,  -0.18, -0.27, -0.3,  0.76,  -0.58, 0.98,  -0.4,  -1.67, 1.2,   0.5,
    -0.43, 0.68,  0.26,  0.63,  -0.06, -0.84, 0.28,  -0.49, 1.55,  0.93,  1.32,  -0.5};

// wraps degrees into (-180, 180]
double WrapDeg(double degrees) {
  double wrapped = std::fmod(degrees, 360.0);
  if (wrapped <= -180.0) wrapped += 360.0;
  if (wrapped > 180.0) wrapped -= 360.0;
  return wrapped;
}

// A sample compared with itself has D = 0 and p = 1, by either method.
TEST(StatisticsTest, IdenticalSamplesGiveDZeroPOne) {
  const KsResult small = KolmogorovSmirnov2(kA, kA);
  EXPECT_EQ(small.d, 0.0);
  EXPECT_EQ(small.p, 1.0);
  EXPECT_EQ(small.method, KsMethod::kExact);
  const KsResult large = KolmogorovSmirnov2(kE, kE);
  EXPECT_EQ(large.d, 0.0);
  EXPECT_EQ(large.p, 1.0);
  EXPECT_EQ(large.method, KsMethod::kAsymptotic);
}

// Samples of 12 and 15 from N(0, 1) and N(1, 1): scipy's exact D and p.
TEST(StatisticsTest, KsExactUnequalSizes) {
  const KsResult result = KolmogorovSmirnov2(kA, kB);
  EXPECT_EQ(result.method, KsMethod::kExact);
  EXPECT_EQ(result.n1, 12);
  EXPECT_EQ(result.n2, 15);
  EXPECT_NEAR(result.d, 0.6166666666666667, 1e-12);
  EXPECT_NEAR(result.p, 0.006831394178278012, 1e-9);
  // the test is symmetric
  const KsResult swapped = KolmogorovSmirnov2(kB, kA);
  EXPECT_DOUBLE_EQ(swapped.d, result.d);
  EXPECT_NEAR(swapped.p, result.p, 1e-12);
}

// Samples of 20 and 20 from N(0, 1) and N(0.8, 1.5): scipy's exact D and p (its n1 == n2 branch,
// a different algorithm from the lattice paths here).
TEST(StatisticsTest, KsExactEqualSizes) {
  const KsResult result = KolmogorovSmirnov2(kC, kD);
  EXPECT_EQ(result.method, KsMethod::kExact);
  EXPECT_NEAR(result.d, 0.35, 1e-12);
  EXPECT_NEAR(result.p, 0.17453300569806826, 1e-9);
}

// Ties within and across samples: D is measured after every equal value, as scipy does.
TEST(StatisticsTest, KsExactWithTies) {
  const KsResult result =
      KolmogorovSmirnov2({0, 0, 1, 1, 1, 2, 2, 3}, {0, 1, 1, 2, 2, 2, 3, 3, 3, 3});
  EXPECT_NEAR(result.d, 0.325, 1e-12);
  EXPECT_NEAR(result.p, 0.6024041318158965, 1e-9);
}

// Fully separated samples of 50 and 40: p = 2 / C(90, 40) = 3.34e-26, kept to relative accuracy.
TEST(StatisticsTest, KsExactTinyPKeepsRelativeAccuracy) {
  std::vector<double> low, high;
  for (int k = 0; k < 50; ++k) low.push_back(k);
  for (int k = 0; k < 40; ++k) high.push_back(100 + k);
  const KsResult result = KolmogorovSmirnov2(low, high);
  EXPECT_EQ(result.d, 1.0);
  EXPECT_NEAR(result.p / 3.340520538602392e-26, 1.0, 1e-9);
}

// Samples of 150 and 120 (n1 n2 > 10000) from N(0, 1) and N(0.4, 1): scipy's D, and p from
// scipy.special.kolmogorov at lambda = D sqrt(n1 n2 / (n1 + n2)).
TEST(StatisticsTest, KsAsymptotic) {
  const KsResult result = KolmogorovSmirnov2(kE, kF);
  EXPECT_EQ(result.method, KsMethod::kAsymptotic);
  EXPECT_STREQ(KsMethodName(result.method), "asymptotic");
  EXPECT_NEAR(result.d, 0.2, 1e-12);
  EXPECT_NEAR(result.lambda, 1.6329931618554527, 1e-12);
  EXPECT_NEAR(result.p, 0.009655898901034446, 1e-9);
}

// The method switches at n1 n2 = 10000: 100 x 100 is exact, 100 x 101 asymptotic.
TEST(StatisticsTest, KsMethodThreshold) {
  std::vector<double> a, b, c;
  for (int k = 0; k < 100; ++k) a.push_back(k);
  for (int k = 0; k < 100; ++k) b.push_back(k + 10.5);
  for (int k = 0; k < 101; ++k) c.push_back(k + 10.5);
  EXPECT_EQ(KolmogorovSmirnov2(a, b).method, KsMethod::kExact);
  EXPECT_EQ(KolmogorovSmirnov2(a, c).method, KsMethod::kAsymptotic);
  // the exact p and the limit agree roughly at this size
  EXPECT_NEAR(KolmogorovSmirnov2(a, b).p, KolmogorovSurvival(KolmogorovSmirnov2(a, b).lambda),
              0.05);
}

// Empty samples and NaN are refused.
TEST(StatisticsTest, KsRefusesBadSamples) {
  EXPECT_THROW(KolmogorovSmirnov2({}, {1.0}), std::invalid_argument);
  EXPECT_THROW(KolmogorovSmirnov2({1.0, std::nan("")}, {1.0}), std::invalid_argument);
}

// Q_KS matches scipy.special.kolmogorov on both sides of the switch between its two series.
TEST(StatisticsTest, KolmogorovSurvivalKnownValues) {
  const std::vector<std::pair<double, double>> known = {
      {0.2, 0.999999999999495},     {0.5, 0.9639452436648751},   {0.8, 0.5441424115741981},
      {1.0, 0.26999967167735456},   {1.1, 0.1777181926064012},   {1.2, 0.11224966667072497},
      {1.358, 0.05002679733444698}, {1.5, 0.022217962616525127}, {2.0, 0.0006709252557796953},
      {3.0, 3.045995948942526e-08}};
  for (const auto& [lambda, q] : known) {
    EXPECT_NEAR(KolmogorovSurvival(lambda), q, 1e-14) << lambda;
  }
  EXPECT_EQ(KolmogorovSurvival(0.0), 1.0);
  EXPECT_EQ(KolmogorovSurvival(-1.0), 1.0);
}

// The chi-square survival function matches scipy.stats.chi2.sf, including the 5 % point of one
// degree of freedom and tails down to 1e-15.
TEST(StatisticsTest, ChiSquareSurvivalKnownValues) {
  struct Known {
    double x;
    int dof;
    double p;
  };
  for (const Known& known : std::vector<Known>{{3.84145882, 1, 0.0500000000206984},
                                               {0.5, 1, 0.47950012218695337},
                                               {10.0, 4, 0.04042768199451279},
                                               {0.5, 7, 0.9994464813904249},
                                               {1e-3, 2, 0.9995001249791693},
                                               {100.0, 50, 3.454931382984871e-05},
                                               {250.0, 200, 0.009379131668826098},
                                               {30.0, 3, 1.3800570312932553e-06},
                                               {80.0, 5, 8.391825114831597e-16},
                                               {5.0, 11, 0.9311666104706992}}) {
    EXPECT_NEAR(ChiSquareSurvival(known.x, known.dof), known.p, 1e-12 + 1e-10 * known.p)
        << known.x << " " << known.dof;
  }
  EXPECT_EQ(ChiSquareSurvival(0.0, 3), 1.0);
  EXPECT_THROW(ChiSquareSurvival(1.0, 0), std::invalid_argument);
}

// Pearson's goodness of fit matches scipy.stats.chisquare.
TEST(StatisticsTest, ChiSquareGoodnessOfFitKnownValues) {
  const ChiSquareResult result = ChiSquareGoodnessOfFit({18, 25, 30, 27}, {0.2, 0.3, 0.3, 0.2});
  EXPECT_NEAR(result.statistic, 3.4833333333333334, 1e-12);
  EXPECT_EQ(result.dof, 3);
  EXPECT_NEAR(result.p, 0.3229301736057768, 1e-10);
  EXPECT_NEAR(result.min_expected, 20.0, 1e-12);
  // a category of probability 0 and no counts is dropped; counts there are refused
  const ChiSquareResult dropped =
      ChiSquareGoodnessOfFit({18, 25, 0, 30, 27}, {0.2, 0.3, 0.0, 0.3, 0.2});
  EXPECT_EQ(dropped.dof, 3);
  EXPECT_NEAR(dropped.p, result.p, 1e-15);
  EXPECT_EQ(dropped.categories, (std::vector<int>{0, 1, 3, 4}));
  EXPECT_THROW(ChiSquareGoodnessOfFit({1, 1}, {1.0, 0.0}), std::invalid_argument);
  EXPECT_THROW(ChiSquareGoodnessOfFit({1, 1}, {0.5, 0.6}), std::invalid_argument);
  EXPECT_THROW(ChiSquareGoodnessOfFit({1}, {0.5, 0.5}), std::invalid_argument);
}

// The 2 x k homogeneity test matches scipy.stats.chi2_contingency(correction=False), with an
// empty category dropped.
TEST(StatisticsTest, ChiSquareHomogeneityKnownValues) {
  const ChiSquareResult result = ChiSquareHomogeneity({40, 25, 20, 0, 15}, {30, 35, 10, 0, 25});
  EXPECT_NEAR(result.statistic, 8.928571428571429, 1e-12);
  EXPECT_EQ(result.dof, 3);
  EXPECT_NEAR(result.p, 0.030255798316947646, 1e-10);
  EXPECT_NEAR(result.min_expected, 15.0, 1e-12);
  EXPECT_EQ(result.categories, (std::vector<int>{0, 1, 2, 4}));
  // equal proportions: statistic 0, p 1; one category in all: dof 0, p 1
  const ChiSquareResult same = ChiSquareHomogeneity({10, 20, 30}, {20, 40, 60});
  EXPECT_NEAR(same.statistic, 0.0, 1e-12);
  EXPECT_NEAR(same.p, 1.0, 1e-12);
  EXPECT_THROW(ChiSquareHomogeneity({5}, {0, 0}), std::invalid_argument);
  EXPECT_EQ(ChiSquareHomogeneity({5, 0}, {7}).dof, 0);
  EXPECT_EQ(ChiSquareHomogeneity({5, 0}, {7}).p, 1.0);
}

// The paper's normalisation removes location and spread: a sample against an affine copy of
// itself gives D = 0; Z follows formula (4).
TEST(StatisticsTest, PaperKsNormalisesEachSample) {
  std::vector<double> moved;
  for (const double value : kE) moved.push_back(3.0 * value + 7.0);
  const PaperKsResult same = PaperKs(kE, moved);
  EXPECT_NEAR(same.d, 0.0, 1e-12);
  EXPECT_NEAR(same.z, 0.0, 1e-12);
  EXPECT_NEAR(same.p, 1.0, 1e-12);
  // the raw test sees the shift; formula (4) on the normalised samples
  EXPECT_GT(KolmogorovSmirnov2(kE, moved).d, 0.5);
  const PaperKsResult paper = PaperKs(kE, kF);
  EXPECT_NEAR(paper.z, paper.d * std::sqrt(150.0 * 120.0 / 270.0), 1e-12);
  EXPECT_NEAR(paper.p, KolmogorovSurvival(paper.z), 1e-15);
  // the normalised sample has mean 0 and sample standard deviation 1
  const std::vector<double> normalised = PaperNormalise(kF);
  double sum = 0.0, squares = 0.0;
  for (const double value : normalised) sum += value;
  for (const double value : normalised) squares += value * value;
  // (to the rounding of 1e-9 per value)
  EXPECT_NEAR(sum / normalised.size(), 0.0, 1e-9);
  EXPECT_NEAR(squares / (normalised.size() - 1), 1.0, 1e-8);
  EXPECT_EQ(PaperNormalise({2.0, 2.0, 2.0}), (std::vector<double>{0.0, 0.0, 0.0}));
}

// Kuiper's V does not depend on where the circle is cut, unlike KS's D; its asymptotic
// survival function gives the textbook 5 % point 1.747.
TEST(StatisticsTest, KuiperIsInvariantToTheWrap) {
  // angles in degrees: the same samples turned by 100 degrees and wrapped to (-180, 180]
  std::vector<double> a, b, turned_a, turned_b;
  for (const double value : kE) a.push_back(WrapDeg(60.0 * value));
  for (const double value : kF) b.push_back(WrapDeg(60.0 * value));
  for (const double value : a) turned_a.push_back(WrapDeg(value + 100.0));
  for (const double value : b) turned_b.push_back(WrapDeg(value + 100.0));
  const KuiperResult before = Kuiper2(a, b);
  const KuiperResult after = Kuiper2(turned_a, turned_b);
  EXPECT_NEAR(before.v, after.v, 1e-12);
  EXPECT_NEAR(before.p, after.p, 1e-12);
  EXPECT_GT(before.v, 0.0);
  EXPECT_NE(KolmogorovSmirnov2(a, b).d, KolmogorovSmirnov2(turned_a, turned_b).d);
  // identical samples, and the critical values
  EXPECT_EQ(Kuiper2(a, a).v, 0.0);
  EXPECT_EQ(Kuiper2(a, a).p, 1.0);
  EXPECT_NEAR(KuiperSurvival(1.747), 0.05, 1e-3);
  EXPECT_NEAR(KuiperSurvival(2.001), 0.01, 1e-3);
}

}  // namespace
}  // namespace stackgen::stats
