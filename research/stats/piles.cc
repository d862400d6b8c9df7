#include "research/stats/piles.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <stdexcept>
#include <utility>

namespace stackgen::stats {
namespace {

// a permuted statistic counts as "at least the observed one" within this relative tolerance:
// the same value summed in another order must not look smaller
constexpr double kTieTolerance = 1e-12;
constexpr int kMinPermutations = 19;
constexpr int kMaxPermutations = 1000000;

enum class Kind {
  kDistance,  // Kolmogorov-Smirnov D
  kCircle,    // Kuiper's V
  kCategory,  // chi-square of homogeneity
};

struct Measure {
  const char* name;
  Kind kind;
  // the part's value; NaN when unknown
  double (*value)(const PostureSample&);
};

const Measure kMeasures[] = {
    {"alpha", Kind::kDistance, [](const PostureSample& s) { return s.alpha_deg; }},
    {"beta", Kind::kDistance, [](const PostureSample& s) { return s.beta_deg; }},
    {"gamma", Kind::kDistance, [](const PostureSample& s) { return s.gamma_deg; }},
    {"heading", Kind::kCircle, [](const PostureSample& s) { return s.heading_deg; }},
    {"face", Kind::kCategory,
     [](const PostureSample& s) {
       return s.resting_face < 0 ? std::nan("") : static_cast<double>(s.resting_face);
     }},
    {"height", Kind::kDistance, [](const PostureSample& s) { return s.world_position_mm.z(); }},
    {"radius", Kind::kDistance,
     [](const PostureSample& s) {
       return std::hypot(s.world_position_mm.x(), s.world_position_mm.y());
     }},
};

// one measure's values of both datasets, laid out for computing its statistic under many
// assignments of the pooled scenes to the two groups
struct Pooled {
  Kind kind = Kind::kDistance;
  // distance and circle: the values in ascending order, the pooled scene of each, and whether
  // the next value differs (the end of a run of ties)
  std::vector<int32_t> scene_of_value;
  std::vector<uint8_t> tie_end;
  // values per pooled scene
  std::vector<int64_t> values_of_scene;
  // category: counts per pooled scene and category (scene * categories + category)
  int categories = 0;
  std::vector<int64_t> counts;
};

// the statistic of `pooled` when pooled scene s belongs to group[s] (0: A, 1: B)
double Statistic(const Pooled& pooled, const std::vector<uint8_t>& group) {
  if (pooled.kind == Kind::kCategory) {
    std::vector<double> rows[2] = {std::vector<double>(pooled.categories, 0.0),
                                   std::vector<double>(pooled.categories, 0.0)};
    const int scenes = static_cast<int>(group.size());
    for (int s = 0; s < scenes; ++s) {
      const int64_t* counts = &pooled.counts[static_cast<size_t>(s) * pooled.categories];
      std::vector<double>& row = rows[group[s]];
      for (int c = 0; c < pooled.categories; ++c) row[c] += static_cast<double>(counts[c]);
    }
    const double n1 = std::accumulate(rows[0].begin(), rows[0].end(), 0.0);
    const double n2 = std::accumulate(rows[1].begin(), rows[1].end(), 0.0);
    if (n1 == 0 || n2 == 0) return 0.0;
    double statistic = 0.0;
    for (int c = 0; c < pooled.categories; ++c) {
      const double total = rows[0][c] + rows[1][c];
      if (total == 0) continue;
      const double expected1 = n1 * total / (n1 + n2), expected2 = n2 * total / (n1 + n2);
      statistic += (rows[0][c] - expected1) * (rows[0][c] - expected1) / expected1 +
                   (rows[1][c] - expected2) * (rows[1][c] - expected2) / expected2;
    }
    return statistic;
  }
  // the largest gaps between the two empirical CDFs, after each run of ties
  int64_t n[2] = {0, 0};
  for (size_t s = 0; s < group.size(); ++s) n[group[s]] += pooled.values_of_scene[s];
  if (n[0] == 0 || n[1] == 0) return 0.0;
  const double step1 = 1.0 / static_cast<double>(n[0]), step2 = 1.0 / static_cast<double>(n[1]);
  int64_t below[2] = {0, 0};
  double above = 0.0, under = 0.0;
  for (size_t k = 0; k < pooled.scene_of_value.size(); ++k) {
    ++below[group[pooled.scene_of_value[k]]];
    if (!pooled.tie_end[k]) continue;
    const double gap = below[0] * step1 - below[1] * step2;
    above = std::max(above, gap);
    under = std::max(under, -gap);
  }
  return pooled.kind == Kind::kCircle ? above + under : std::max(above, under);
}

// A measure's pooled values (value, pooled scene) of `kind` over `scenes` scenes, ready for
// Statistic: per-scene counts of each category, or the scenes of the sorted values and their ties.
Pooled Pool(std::vector<std::pair<double, int32_t>> values, Kind kind, int scenes) {
  Pooled pooled;
  pooled.kind = kind;
  pooled.values_of_scene.assign(scenes, 0);
  for (const auto& [value, scene] : values) ++pooled.values_of_scene[scene];
  if (kind == Kind::kCategory) {
    for (const auto& [value, scene] : values) {
      pooled.categories = std::max(pooled.categories, static_cast<int>(value) + 1);
    }
    pooled.counts.assign(static_cast<size_t>(scenes) * pooled.categories, 0);
    for (const auto& [value, scene] : values) {
      ++pooled.counts[static_cast<size_t>(scene) * pooled.categories + static_cast<int>(value)];
    }
  } else {
    std::sort(values.begin(), values.end());
    for (size_t k = 0; k < values.size(); ++k) {
      pooled.scene_of_value.push_back(values[k].second);
      pooled.tie_end.push_back(k + 1 == values.size() || values[k + 1].first != values[k].first);
    }
  }
  return pooled;
}

// How many categories of a category measure occur at all.
int UsedCategories(const Pooled& pooled) {
  const int scenes = static_cast<int>(pooled.values_of_scene.size());
  int used = 0;
  for (int c = 0; c < pooled.categories; ++c) {
    int64_t total = 0;
    for (int s = 0; s < scenes; ++s) {
      total += pooled.counts[static_cast<size_t>(s) * pooled.categories + c];
    }
    used += total > 0 ? 1 : 0;
  }
  return used;
}

// For each measure, how many of options.permutations random reassignments of whole scenes
// (piles_a to A, the rest to B; the same reassignments for every measure) give a statistic at
// least the observed one (tests[m].value).
std::vector<int64_t> CountAtLeast(const std::vector<Pooled>& measures,
                                  const std::vector<PileTest>& tests, int64_t piles_a,
                                  const PileOptions& options) {
  const int scenes = measures.empty() ? 0 : static_cast<int>(measures[0].values_of_scene.size());
  std::mt19937_64 engine(options.seed);
  std::vector<int32_t> order(scenes);
  std::iota(order.begin(), order.end(), 0);
  std::vector<int64_t> at_least(measures.size(), 0);
  std::vector<uint8_t> permuted(scenes);
  for (int k = 0; k < options.permutations; ++k) {
    std::shuffle(order.begin(), order.end(), engine);
    for (int s = 0; s < scenes; ++s) permuted[order[s]] = s < piles_a ? 0 : 1;
    for (size_t m = 0; m < measures.size(); ++m) {
      const double observed = tests[m].value;
      if (Statistic(measures[m], permuted) >= observed * (1.0 - kTieTolerance)) ++at_least[m];
    }
  }
  return at_least;
}

}  // namespace

std::vector<double> HolmAdjust(const std::vector<double>& p) {
  for (const double value : p) {
    if (!(value >= 0 && value <= 1)) {
      throw std::invalid_argument("HolmAdjust: p-value " + std::to_string(value) +
                                  " is not in [0, 1]");
    }
  }
  std::vector<size_t> order(p.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return p[a] < p[b]; });
  std::vector<double> adjusted(p.size());
  const double m = static_cast<double>(p.size());
  double running = 0.0;
  for (size_t rank = 0; rank < order.size(); ++rank) {
    running = std::max(running, std::min(1.0, (m - static_cast<double>(rank)) * p[order[rank]]));
    adjusted[order[rank]] = running;
  }
  return adjusted;
}

PileComparison ComparePiles(const Dataset& a, const Dataset& b, const PileOptions& options) {
  if (options.permutations < kMinPermutations || options.permutations > kMaxPermutations) {
    throw std::invalid_argument("permutations must be " + std::to_string(kMinPermutations) + ".." +
                                std::to_string(kMaxPermutations) + ", got " +
                                std::to_string(options.permutations));
  }
  if (!(options.significance > 0 && options.significance < 1)) {
    throw std::invalid_argument("significance must be in (0, 1), got " +
                                std::to_string(options.significance));
  }
  if (a.samples.empty() || b.samples.empty()) {
    throw std::invalid_argument((a.samples.empty() ? a.path : b.path) + " holds no instances");
  }

  // the pooled scenes that hold a part: A's first
  std::map<std::pair<int, int64_t>, int32_t> pooled_scene;
  PileComparison comparison;
  const Dataset* datasets[2] = {&a, &b};
  for (int d = 0; d < 2; ++d) {
    for (const PostureSample& sample : datasets[d]->samples) {
      const auto key = std::make_pair(d, sample.pile);
      if (pooled_scene.count(key) == 0) {
        pooled_scene.emplace(key, static_cast<int32_t>(pooled_scene.size()));
        ++(d == 0 ? comparison.piles_a : comparison.piles_b);
      }
    }
  }
  const int scenes = static_cast<int>(pooled_scene.size());
  std::vector<uint8_t> group(scenes, 1);
  for (int s = 0; s < comparison.piles_a; ++s) group[s] = 0;

  // each measure's values, and its statistic between A and B
  std::vector<Pooled> measures;
  for (const Measure& measure : kMeasures) {
    std::vector<std::pair<double, int32_t>> values;  // value, pooled scene
    int64_t n[2] = {0, 0};
    for (int d = 0; d < 2; ++d) {
      for (const PostureSample& sample : datasets[d]->samples) {
        const double value = measure.value(sample);
        if (std::isnan(value)) continue;
        values.emplace_back(value, pooled_scene.at({d, sample.pile}));
        ++n[d];
      }
    }
    if (n[0] == 0 || n[1] == 0) {
      comparison.left_out.push_back(std::string(measure.name) + ": " + (n[0] == 0 ? "A" : "B") +
                                    " does not give it");
      continue;
    }
    Pooled pooled = Pool(values, measure.kind, scenes);
    PileTest test;
    test.name = measure.name;
    test.statistic =
        measure.kind == Kind::kDistance ? "D" : (measure.kind == Kind::kCircle ? "V" : "chi2");
    test.value = Statistic(pooled, group);
    test.n1 = n[0];
    test.n2 = n[1];
    if (measure.kind == Kind::kCategory) test.dof = std::max(0, UsedCategories(pooled) - 1);
    comparison.tests.push_back(test);
    measures.push_back(std::move(pooled));
  }

  // the same permutations of whole scenes for every measure
  const std::vector<int64_t> at_least =
      CountAtLeast(measures, comparison.tests, comparison.piles_a, options);

  // p-values, corrected for the family
  std::vector<double> p;
  for (size_t m = 0; m < measures.size(); ++m) {
    comparison.tests[m].p = (1.0 + static_cast<double>(at_least[m])) / (1.0 + options.permutations);
    p.push_back(comparison.tests[m].p);
  }
  const std::vector<double> adjusted = HolmAdjust(p);
  for (size_t m = 0; m < measures.size(); ++m) {
    comparison.tests[m].p_holm = adjusted[m];
    comparison.tests[m].different = adjusted[m] < options.significance;
    comparison.different = comparison.different || comparison.tests[m].different;
  }
  return comparison;
}

std::pair<Dataset, Dataset> SplitScenes(const Dataset& dataset, const std::vector<bool>& first) {
  if (static_cast<int64_t>(first.size()) != dataset.scenes) {
    throw std::invalid_argument("SplitScenes: " + std::to_string(first.size()) + " flags for " +
                                std::to_string(dataset.scenes) + " scenes");
  }
  std::pair<Dataset, Dataset> halves;
  Dataset* parts[2] = {&halves.first, &halves.second};
  for (Dataset* part : parts) {
    part->path = dataset.path;
    part->kind = dataset.kind;
  }
  halves.first.scenes = std::count(first.begin(), first.end(), true);
  halves.second.scenes = dataset.scenes - halves.first.scenes;
  std::set<int64_t> piles[2];
  halves.first.path += " (first part)";
  halves.second.path += " (second part)";
  for (const PostureSample& sample : dataset.samples) {
    const int half = first.at(sample.scene) ? 0 : 1;
    Dataset* part = parts[half];
    part->samples.push_back(sample);
    piles[half].insert(sample.pile);
    ++part->class_counts[sample.class_name];
  }
  halves.first.piles = static_cast<int64_t>(piles[0].size());
  halves.second.piles = static_cast<int64_t>(piles[1].size());
  return halves;
}

}  // namespace stackgen::stats
