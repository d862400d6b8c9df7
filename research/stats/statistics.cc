#include "research/stats/statistics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

namespace stackgen::stats {
namespace {

constexpr double kPi = 3.14159265358979323846;

// throws unless `sample` is non-empty and free of NaN; `name` says which one in the message.
void CheckSample(const std::vector<double>& sample, const char* name) {
  if (sample.empty()) throw std::invalid_argument(std::string("sample ") + name + " is empty");
  for (size_t k = 0; k < sample.size(); ++k) {
    if (std::isnan(sample[k])) {
      throw std::invalid_argument(std::string("sample ") + name + " holds a NaN at index " +
                                  std::to_string(k));
    }
  }
}

// the largest positive and negative distance between the empirical CDFs of two sorted samples,
// in units of 1 / (n1 n2): F1 - F2 = (i n2 - j n1) / (n1 n2) after i values of `a` and j of `b`.
// every value equal to x is taken from both samples before the distance at x is measured.
struct CdfDistance {
  int64_t plus = 0;   // max (i n2 - j n1), >= 0
  int64_t minus = 0;  // max (j n1 - i n2), >= 0
};

CdfDistance SortedCdfDistance(const std::vector<double>& a, const std::vector<double>& b) {
  const int64_t n1 = static_cast<int64_t>(a.size());
  const int64_t n2 = static_cast<int64_t>(b.size());
  CdfDistance distance;
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const double x = std::min(a[i], b[j]);
    while (i < a.size() && a[i] == x) ++i;
    while (j < b.size() && b[j] == x) ++j;
    const int64_t difference = static_cast<int64_t>(i) * n2 - static_cast<int64_t>(j) * n1;
    distance.plus = std::max(distance.plus, difference);
    distance.minus = std::max(distance.minus, -difference);
  }
  // once one sample is used up the distance only shrinks towards 0 at (n1, n2)
  return distance;
}

// P(max_k |i_k n2 - j_k n1| >= d_units) for a uniformly random ordering of n1 + n2 values: the
// probability that a random monotone lattice path from (0, 0) to (n1, n2) leaves the band
// |i n2 - j n1| < d_units. Summed over the points where the path first leaves it, each weighted
// by the probability of reaching it through the band (a path at (i, j) steps to i + 1 with
// probability (n1 - i) / (n1 + n2 - i - j)); all numbers stay in [0, 1].
double ExactOutsideProbability(int64_t n1, int64_t n2, int64_t d_units) {
  if (d_units <= 0) return 1.0;
  const auto inside = [&](int64_t i, int64_t j) { return std::llabs(i * n2 - j * n1) < d_units; };
  const int64_t total = n1 + n2;
  // reach[j]: probability of being at (i, j) with every earlier point inside the band
  std::vector<double> reach(static_cast<size_t>(n2 + 1), 0.0);
  double outside = 0.0;
  for (int64_t i = 0; i <= n1; ++i) {
    for (int64_t j = 0; j <= n2; ++j) {
      double here = 0.0;
      if (i == 0 && j == 0) {
        here = 1.0;
      } else {
        const double remaining = static_cast<double>(total - i - j + 1);
        // from (i - 1, j): reach[j] still holds row i - 1
        if (i > 0 && inside(i - 1, j))
          here += reach[j] * static_cast<double>(n1 - i + 1) / remaining;
        // from (i, j - 1): reach[j - 1] already holds row i
        if (j > 0 && inside(i, j - 1)) {
          here += reach[j - 1] * static_cast<double>(n2 - j + 1) / remaining;
        }
      }
      reach[j] = here;
      if (!inside(i, j)) outside += here;
    }
  }
  return std::min(1.0, outside);
}

}  // namespace

const char* KsMethodName(KsMethod method) {
  return method == KsMethod::kExact ? "exact" : "asymptotic";
}

KsResult KolmogorovSmirnov2(std::vector<double> a, std::vector<double> b) {
  CheckSample(a, "a");
  CheckSample(b, "b");
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());

  // D in units of 1 / (n1 n2), exact
  KsResult result;
  result.n1 = static_cast<int64_t>(a.size());
  result.n2 = static_cast<int64_t>(b.size());
  const CdfDistance distance = SortedCdfDistance(a, b);
  const int64_t d_units = std::max(distance.plus, distance.minus);
  const double n1 = static_cast<double>(result.n1), n2 = static_cast<double>(result.n2);
  result.d = static_cast<double>(d_units) / (n1 * n2);
  result.lambda = result.d * std::sqrt(n1 * n2 / (n1 + n2));

  // the p-value: exact for small samples, Kolmogorov's limit otherwise
  if (result.n1 * result.n2 <= kKsExactMaxProduct) {
    result.method = KsMethod::kExact;
    result.p = ExactOutsideProbability(result.n1, result.n2, d_units);
  } else {
    result.method = KsMethod::kAsymptotic;
    result.p = KolmogorovSurvival(result.lambda);
  }
  return result;
}

double KolmogorovSurvival(double lambda) {
  if (std::isnan(lambda)) return lambda;
  if (lambda <= 0.0) return 1.0;
  if (lambda < 1.18) {
    // small lambda: the Jacobi-transformed CDF, sqrt(2 pi) / lambda sum exp(-(2k-1)^2 pi^2 /
    // (8 lambda^2)), converges in a few terms
    const double w = kPi * kPi / (8.0 * lambda * lambda);
    double sum = 0.0;
    for (int k = 1; k < 100; ++k) {
      const double term = std::exp(-static_cast<double>((2 * k - 1) * (2 * k - 1)) * w);
      sum += term;
      if (term < 1e-17 * sum || term == 0.0) break;
    }
    return 1.0 - std::sqrt(2.0 * kPi) / lambda * sum;
  }
  // large lambda: the alternating series converges fast
  double sum = 0.0;
  for (int k = 1; k < 100; ++k) {
    const double term = std::exp(-2.0 * k * k * lambda * lambda);
    sum += (k % 2 == 1) ? term : -term;
    if (term < 1e-17 * sum || term == 0.0) break;
  }
  return std::clamp(2.0 * sum, 0.0, 1.0);
}

KuiperResult Kuiper2(std::vector<double> a, std::vector<double> b) {
  CheckSample(a, "a");
  CheckSample(b, "b");
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());

  // V = D+ + D-, both in units of 1 / (n1 n2)
  KuiperResult result;
  result.n1 = static_cast<int64_t>(a.size());
  result.n2 = static_cast<int64_t>(b.size());
  const CdfDistance distance = SortedCdfDistance(a, b);
  const double n1 = static_cast<double>(result.n1), n2 = static_cast<double>(result.n2);
  result.v = static_cast<double>(distance.plus + distance.minus) / (n1 * n2);

  // Stephens' small-sample correction of the limit
  const double root_ne = std::sqrt(n1 * n2 / (n1 + n2));
  result.p = KuiperSurvival((root_ne + 0.155 + 0.24 / root_ne) * result.v);
  return result;
}

double KuiperSurvival(double lambda) {
  if (std::isnan(lambda)) return lambda;
  if (lambda < 0.4) return 1.0;
  double sum = 0.0;
  for (int k = 1; k < 100; ++k) {
    const double k2l2 = static_cast<double>(k) * k * lambda * lambda;
    const double term = (4.0 * k2l2 - 1.0) * std::exp(-2.0 * k2l2);
    sum += term;
    if (std::fabs(term) < 1e-17 * std::fabs(sum) || term == 0.0) break;
  }
  return std::clamp(2.0 * sum, 0.0, 1.0);
}

double ChiSquareSurvival(double x, int dof) {
  if (dof < 1) throw std::invalid_argument("chi-square needs dof >= 1, got " + std::to_string(dof));
  if (std::isnan(x)) throw std::invalid_argument("chi-square statistic is NaN");
  if (x <= 0.0) return 1.0;
  if (std::isinf(x)) return 0.0;
  const double a = 0.5 * dof;
  const double z = 0.5 * x;
  // z^a e^-z / Gamma(a), the factor both expansions share
  const double front = std::exp(a * std::log(z) - z - std::lgamma(a));
  constexpr double kEpsilon = 1e-16;
  constexpr int kMaxIterations = 100000;
  if (z < a + 1.0) {
    // series for the lower function P(a, z) = front * sum z^n / (a (a+1) ... (a+n))
    double term = 1.0 / a, sum = term;
    for (int n = 1; n < kMaxIterations; ++n) {
      term *= z / (a + n);
      sum += term;
      if (term < kEpsilon * sum) break;
    }
    return std::clamp(1.0 - front * sum, 0.0, 1.0);
  }
  // continued fraction for the upper function Q(a, z) (modified Lentz)
  constexpr double kTiny = 1e-300;
  double b = z + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int n = 1; n < kMaxIterations; ++n) {
    const double an = -n * (n - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::fabs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < kEpsilon) break;
  }
  return std::clamp(front * h, 0.0, 1.0);
}

ChiSquareResult ChiSquareGoodnessOfFit(const std::vector<int64_t>& counts,
                                       const std::vector<double>& expected_probabilities) {
  if (counts.size() != expected_probabilities.size()) {
    throw std::invalid_argument("goodness of fit: " + std::to_string(counts.size()) +
                                " counts but " + std::to_string(expected_probabilities.size()) +
                                " probabilities");
  }
  // check the inputs
  int64_t total = 0;
  double probability_sum = 0.0;
  for (size_t k = 0; k < counts.size(); ++k) {
    if (counts[k] < 0) {
      throw std::invalid_argument("goodness of fit: count " + std::to_string(k) + " is negative");
    }
    if (!(expected_probabilities[k] >= 0.0)) {
      throw std::invalid_argument("goodness of fit: probability " + std::to_string(k) +
                                  " is negative or NaN");
    }
    if (expected_probabilities[k] == 0.0 && counts[k] > 0) {
      throw std::invalid_argument("goodness of fit: category " + std::to_string(k) +
                                  " has counts but probability 0");
    }
    total += counts[k];
    probability_sum += expected_probabilities[k];
  }
  if (std::fabs(probability_sum - 1.0) > 1e-9) {
    throw std::invalid_argument("goodness of fit: probabilities sum to " +
                                std::to_string(probability_sum) + ", not 1");
  }
  if (total == 0) throw std::invalid_argument("goodness of fit: no counts");

  // the statistic over categories of nonzero probability
  ChiSquareResult result;
  result.min_expected = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < counts.size(); ++k) {
    if (expected_probabilities[k] == 0.0) continue;
    const double expected = static_cast<double>(total) * expected_probabilities[k];
    const double difference = static_cast<double>(counts[k]) - expected;
    result.statistic += difference * difference / expected;
    result.min_expected = std::min(result.min_expected, expected);
    result.categories.push_back(static_cast<int>(k));
  }
  result.dof = static_cast<int>(result.categories.size()) - 1;
  result.p = result.dof >= 1 ? ChiSquareSurvival(result.statistic, result.dof) : 1.0;
  return result;
}

ChiSquareResult ChiSquareHomogeneity(const std::vector<int64_t>& counts_a,
                                     const std::vector<int64_t>& counts_b) {
  // pad to one length and check
  const size_t k = std::max(counts_a.size(), counts_b.size());
  std::vector<int64_t> a = counts_a, b = counts_b;
  a.resize(k, 0);
  b.resize(k, 0);
  int64_t total_a = 0, total_b = 0;
  for (size_t c = 0; c < k; ++c) {
    if (a[c] < 0 || b[c] < 0) {
      throw std::invalid_argument("homogeneity: count of category " + std::to_string(c) +
                                  " is negative");
    }
    total_a += a[c];
    total_b += b[c];
  }
  if (total_a == 0 || total_b == 0) {
    throw std::invalid_argument(std::string("homogeneity: sample ") + (total_a == 0 ? "a" : "b") +
                                " has no counts");
  }

  // expected cell counts row total x column total / grand total, over non-empty columns
  ChiSquareResult result;
  result.min_expected = std::numeric_limits<double>::infinity();
  const double total = static_cast<double>(total_a + total_b);
  for (size_t c = 0; c < k; ++c) {
    const int64_t column = a[c] + b[c];
    if (column == 0) continue;
    for (const auto& [observed, row] :
         {std::pair<int64_t, int64_t>{a[c], total_a}, std::pair<int64_t, int64_t>{b[c], total_b}}) {
      const double expected = static_cast<double>(row) * static_cast<double>(column) / total;
      const double difference = static_cast<double>(observed) - expected;
      result.statistic += difference * difference / expected;
      result.min_expected = std::min(result.min_expected, expected);
    }
    result.categories.push_back(static_cast<int>(c));
  }
  result.dof = static_cast<int>(result.categories.size()) - 1;
  result.p = result.dof >= 1 ? ChiSquareSurvival(result.statistic, result.dof) : 1.0;
  return result;
}

std::vector<double> PaperNormalise(const std::vector<double>& sample) {
  CheckSample(sample, "to normalise");
  // min-max to [0, 1]
  const auto [lowest, highest] = std::minmax_element(sample.begin(), sample.end());
  const double low = *lowest, range = *highest - *lowest;
  std::vector<double> normalised(sample.size(), 0.0);
  if (range == 0.0 || sample.size() < 2) return normalised;
  for (size_t k = 0; k < sample.size(); ++k) normalised[k] = (sample[k] - low) / range;

  // then mean 0, sample standard deviation 1
  const double n = static_cast<double>(sample.size());
  const double mean = std::accumulate(normalised.begin(), normalised.end(), 0.0) / n;
  double squares = 0.0;
  for (const double value : normalised) squares += (value - mean) * (value - mean);
  const double sd = std::sqrt(squares / (n - 1.0));
  for (double& value : normalised) value = (value - mean) / sd;

  // rounded to 1e-9, so values equal before normalisation stay equal after it (the two samples
  // are normalised with different numbers, and rounding errors would otherwise split ties)
  for (double& value : normalised) value = std::round(value * 1e9) / 1e9;
  return normalised;
}

PaperKsResult PaperKs(const std::vector<double>& a, const std::vector<double>& b) {
  std::vector<double> normalised_a = PaperNormalise(a);
  std::vector<double> normalised_b = PaperNormalise(b);
  std::sort(normalised_a.begin(), normalised_a.end());
  std::sort(normalised_b.begin(), normalised_b.end());

  // D on the normalised samples, then formula (4)
  PaperKsResult result;
  result.n1 = static_cast<int64_t>(a.size());
  result.n2 = static_cast<int64_t>(b.size());
  const CdfDistance distance = SortedCdfDistance(normalised_a, normalised_b);
  const double n1 = static_cast<double>(result.n1), n2 = static_cast<double>(result.n2);
  result.d = static_cast<double>(std::max(distance.plus, distance.minus)) / (n1 * n2);
  result.z = result.d * std::sqrt(n1 * n2 / (n1 + n2));
  result.p = KolmogorovSurvival(result.z);
  return result;
}

}  // namespace stackgen::stats
