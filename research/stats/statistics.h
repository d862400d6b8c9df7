#pragma once

// Two-sample tests for comparing posture distributions: Kolmogorov-Smirnov (exact and
// asymptotic), Kuiper (for angles on a circle), chi-square (goodness of fit and homogeneity), and
// the paper's normalised KS statistic (Zhang et al. 2021, formula (4)). Plain C++, no
// dependencies; every function is pure and thread-safe.

#include <cstdint>
#include <vector>

namespace stackgen::stats {

/// How a KS p-value was computed.
enum class KsMethod {
  /// The exact distribution of D under the null hypothesis (lattice-path counting).
  kExact,
  /// The limiting Kolmogorov distribution, Q_KS(D * sqrt(n1 n2 / (n1 + n2))).
  kAsymptotic,
};

/// "exact" or "asymptotic".
const char* KsMethodName(KsMethod method);

/// The largest n1 * n2 for which KolmogorovSmirnov2 computes the exact p-value.
inline constexpr int64_t kKsExactMaxProduct = 10000;

/// The result of a two-sample Kolmogorov-Smirnov test.
struct KsResult {
  /// D = sup_x |F1(x) - F2(x)| over the two empirical CDFs, in [0, 1].
  double d = 0.0;
  /// Two-sided p-value: the probability, if both samples come from one continuous
  /// distribution, of a D at least this large.
  double p = 1.0;
  /// How `p` was computed.
  KsMethod method = KsMethod::kExact;
  /// lambda = D * sqrt(n1 n2 / (n1 + n2)), the argument of the Kolmogorov distribution (the
  /// paper's Z in formula (4) when computed on its normalised samples).
  double lambda = 0.0;
  int64_t n1 = 0;
  int64_t n2 = 0;
};

/// The two-sample, two-sided Kolmogorov-Smirnov test of `a` against `b`.
///
/// D is the largest distance between the empirical CDFs, evaluated after all values equal to x
/// in both samples (ties within and across samples are handled exactly, like
/// scipy.stats.ks_2samp). The p-value is
/// - exact when n1 * n2 <= kKsExactMaxProduct: P(D' >= D) under the null hypothesis, counted
///   over the C(n1 + n2, n1) equally likely orderings of the pooled sample as monotone lattice
///   paths from (0, 0) to (n1, n2) that touch the band |i/n1 - j/n2| >= D (Hodges 1957; the
///   same number scipy.stats.ks_2samp(method='exact') gives). The outside probability is summed
///   over first touches, so a small p keeps its relative accuracy;
/// - asymptotic otherwise: Q_KS(lambda) with lambda = D * sqrt(n1 n2 / (n1 + n2)) (Smirnov's
///   limit; scipy's method='asymp' uses a finite-n one-sample distribution instead, which
///   differs from this in the third decimal for n of a few hundred).
/// With ties the exact and asymptotic p-values are those of continuous data (conservative).
/// Throws std::invalid_argument if a sample is empty or holds a NaN.
KsResult KolmogorovSmirnov2(std::vector<double> a, std::vector<double> b);

/// The survival function of the Kolmogorov distribution,
/// Q_KS(lambda) = 2 sum_{k>=1} (-1)^(k-1) exp(-2 k^2 lambda^2), 1 for lambda <= 0 (the same as
/// scipy.special.kolmogorov). Absolute error below 1e-15.
double KolmogorovSurvival(double lambda);

/// The result of a two-sample Kuiper test.
struct KuiperResult {
  /// V = max(F1 - F2) + max(F2 - F1), in [0, 1]; unchanged by where a circle is cut open.
  double v = 0.0;
  /// Asymptotic p-value, Q_KP((sqrt(Ne) + 0.155 + 0.24 / sqrt(Ne)) V) with Ne = n1 n2 / (n1 + n2)
  /// (Stephens 1970, as in Numerical Recipes' kptwo).
  double p = 1.0;
  int64_t n1 = 0;
  int64_t n2 = 0;
};

/// The two-sample Kuiper test, the KS test for values on a circle (angles): V and its p-value
/// do not depend on the origin of the angles, so a distribution split by the +-180 degree wrap
/// is compared fairly. Throws std::invalid_argument if a sample is empty or holds a NaN.
KuiperResult Kuiper2(std::vector<double> a, std::vector<double> b);

/// The survival function of Kuiper's distribution,
/// Q_KP(lambda) = 2 sum_{k>=1} (4 k^2 lambda^2 - 1) exp(-2 k^2 lambda^2), 1 for lambda < 0.4.
double KuiperSurvival(double lambda);

/// The survival function of the chi-square distribution with `dof` degrees of freedom:
/// P(X >= x) = Q(dof / 2, x / 2), the regularised upper incomplete gamma function (series or
/// continued fraction, relative accuracy about 1e-14). 1 for x <= 0. Throws
/// std::invalid_argument if dof < 1 or x is NaN.
double ChiSquareSurvival(double x, int dof);

/// The result of a chi-square test.
struct ChiSquareResult {
  /// sum (observed - expected)^2 / expected over the cells used.
  double statistic = 0.0;
  /// Degrees of freedom; 0 when fewer than two categories remain (then p = 1).
  int dof = 0;
  /// P(chi2_dof >= statistic); 1 when dof is 0.
  double p = 1.0;
  /// The smallest expected count of a cell used: the chi-square approximation wants >= 5.
  double min_expected = 0.0;
  /// The categories used, indices into the inputs.
  std::vector<int> categories;
};

/// Pearson's goodness-of-fit test of `counts` (one per category) against
/// `expected_probabilities` (same length, each >= 0, summing to 1 within 1e-9). Categories with
/// probability 0 and count 0 are dropped; dof = categories used - 1. Throws
/// std::invalid_argument on different lengths, a negative count or probability, probabilities
/// not summing to 1, no counts at all, or a count in a category of probability 0.
ChiSquareResult ChiSquareGoodnessOfFit(const std::vector<int64_t>& counts,
                                       const std::vector<double>& expected_probabilities);

/// Pearson's test of homogeneity of two samples of a categorical variable: the 2 x k
/// contingency table with rows `counts_a` and `counts_b` (the shorter padded with zeros).
/// Categories with a zero total are dropped; dof = categories used - 1; no continuity
/// correction (scipy.stats.chi2_contingency(correction=False)). Throws std::invalid_argument on a
/// negative count or when a row is all zero.
ChiSquareResult ChiSquareHomogeneity(const std::vector<int64_t>& counts_a,
                                     const std::vector<int64_t>& counts_b);

/// The paper's KS statistic (Zhang et al. 2021, section 4 and formula (4)).
struct PaperKsResult {
  /// D between the two normalised samples.
  double d = 0.0;
  /// Z = D * sqrt(n1 n2 / (n1 + n2)), formula (4).
  double z = 0.0;
  /// Q_KS(Z): the p-value that Z gives from the Kolmogorov distribution. Small means the shapes
  /// differ (the paper reads it the other way round).
  double p = 1.0;
  int64_t n1 = 0;
  int64_t n2 = 0;
};

/// The paper's procedure: each sample on its own is min-max normalised to [0, 1] and then
/// standardised to mean 0 and sample standard deviation 1 (n - 1 in the denominator), and D and
/// Z = D * sqrt(n1 n2 / (n1 + n2)) are computed on the results. Both steps are affine, so the
/// result equals standardising alone: the test then compares only the shapes of the two
/// distributions, with their location and spread removed. (Normalising the pooled data instead
/// would change nothing, since D is invariant under a common monotone map.) A sample whose
/// values are all equal normalises to all zeros. Normalised values are rounded to 1e-9 so that
/// ties across the two samples survive floating-point rounding. Throws std::invalid_argument if
/// a sample is empty or holds a NaN.
PaperKsResult PaperKs(const std::vector<double>& a, const std::vector<double>& b);

/// The paper's normalisation of one sample (see PaperKs). Throws like PaperKs.
std::vector<double> PaperNormalise(const std::vector<double>& sample);

}  // namespace stackgen::stats
