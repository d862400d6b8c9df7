// stackgen-rest-check: are a config's piles at rest when they are published? Drops piles as
// the generator does, goes on simulating each after it was published until it is at rest by a
// strict rule, and says how far the parts still moved, on which faces they lie, and what the
// physics cost.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "cli/flags.h"
#include "gen/config/config.h"
#include "gen/physics/hull_faces.h"
#include "gen/physics/pile.h"
#include "gen/scene/scene_generator.h"

namespace {

constexpr const char* kUsage = R"(usage: stackgen-rest-check [--config FILE] [--count N] [--seed S]
                           [--generator-id G] [--cache-dir DIR] [--strict-mm D]
                           [--strict-deg A] [--strict-window-s W] [--strict-max-s T]

Drops the first N piles (default 20) that `stackgen --config FILE --seed S --generator-id G`
would publish (the same drops and redraws; piles as dropped, before any pick), and after the
moment the generator's settle rule published each, goes on simulating the same world until
every part moved less than D mm (default 0.1) and turned less than A degrees (default 0.1) over
W seconds (default 1), or T seconds more passed (default 60). A pile published at rest hardly
moves on; one published while it still crept or toppled does.
Prints, over all parts: the share that moved more than 1 mm or 1 degree, and more than 5 mm or
10 degrees; how far the heaps sank; how many piles came to rest; the faces of each part type's
convex hull the parts rest on (0 = the largest), as published and after; the physics time per
pile (median and mean) and the shares of it spent on redrawn drops and on drops not at rest in
time.
)";

double Median(std::vector<double> values) {
  if (values.empty()) return 0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : (values[n / 2 - 1] + values[n / 2]) / 2;
}

double Percent(int64_t part, int64_t whole) { return whole > 0 ? 100.0 * part / whole : 0.0; }

// "0 41.2 %, 1 40.0 %, ..." for each type's resting faces, most common first
std::string FaceShares(const std::vector<std::map<int, int64_t>>& faces, bool several_types) {
  std::string text;
  for (size_t t = 0; t < faces.size(); ++t) {
    int64_t total = 0;
    for (const auto& [face, count] : faces[t]) total += count;
    if (total == 0) continue;
    std::vector<std::pair<int64_t, int>> order;
    for (const auto& [face, count] : faces[t]) order.emplace_back(-count, face);
    std::sort(order.begin(), order.end());
    if (!text.empty()) text += "; ";
    if (several_types) text += "type " + std::to_string(t) + ": ";
    for (size_t k = 0; k < order.size(); ++k) {
      char item[64];
      std::snprintf(item, sizeof(item), "%s%d %.1f %%", k == 0 ? "" : ", ", order[k].second,
                    Percent(-order[k].first, total));
      text += item;
    }
  }
  return text;
}

// What the parts of the piles did, summed over the piles.
struct Tally {
  std::vector<std::map<int, int64_t>> faces_before, faces_after;  // per type: face -> parts
  std::vector<double> physics_ms, resettle_s;                     // per pile
  stackgen::StageTimes redraws;
  int64_t parts = 0, moved = 0, moved_far = 0, at_rest = 0, shifted = 0, turned = 0;
  std::vector<double> shifts_mm, turns_deg;  // per part
  double sank_mm = 0;
};

// What one pile's parts did between being published (`pile`) and strict rest (`again`).
void Count(const stackgen::PileSimulator& simulator, const stackgen::SettledPile& pile,
           const stackgen::PileResult& again, Tally* t) {
  t->resettle_s.push_back(again.simulated_s);
  t->at_rest += again.settled ? 1 : 0;
  for (size_t i = 0; i < pile.object_types.size(); ++i) {
    const int type = pile.object_types[i];
    const Eigen::Isometry3d& before = pile.world_from_object[i];
    const Eigen::Isometry3d& after = again.world_from_object[i];
    const double moved_mm = (after.translation() - before.translation()).norm();
    const double turned_deg =
        Eigen::AngleAxisd(after.linear() * before.linear().transpose()).angle() * 180 / M_PI;
    ++t->parts;
    t->moved += moved_mm > 1 || turned_deg > 1 ? 1 : 0;
    t->shifted += moved_mm > 1 ? 1 : 0;
    t->turned += turned_deg > 1 ? 1 : 0;
    t->shifts_mm.push_back(moved_mm);
    t->turns_deg.push_back(turned_deg);
    t->moved_far += moved_mm > 5 || turned_deg > 10 ? 1 : 0;
    t->sank_mm += before.translation().z() - after.translation().z();
    const auto& hull = simulator.hull_faces(type);
    ++t->faces_before[type][stackgen::RestingFace(hull, before.linear())];
    ++t->faces_after[type][stackgen::RestingFace(hull, after.linear())];
  }
}

// Prints the tally of `count` piles (after the line's start, which names the config).
void Print(const Tally& t, const stackgen::RestRule& rule, int64_t count, bool several_types) {
  std::printf(
      "%lld parts; physics %.1f ms per pile (median), %d drops redrawn (%d unsettled, %d "
      "outside the bin, %d interpenetrating)\n",
      static_cast<long long>(t.parts), Median(t.physics_ms), t.redraws.redraws,
      t.redraws.redraws_unsettled, t.redraws.redraws_outside, t.redraws.redraws_penetrating);
  const double all_ms = std::accumulate(t.physics_ms.begin(), t.physics_ms.end(), 0.0);
  const double total = std::max(all_ms, 1e-9);
  std::printf(
      "stackgen-rest-check: of all the physics (%.1f ms a published pile on average), %.1f %% "
      "went to redrawn drops, %.1f %% to drops not at rest in time\n",
      all_ms / std::max<int64_t>(count, 1), 100 * t.redraws.redrawn_physics_ms / total,
      100 * t.redraws.unsettled_physics_ms / total);
  std::printf(
      "stackgen-rest-check: going on to strict rest (every part < %g mm and < %g deg over %g s, "
      "at most %g s more): %lld of %lld piles came to rest, in %.2f s (median)\n",
      rule.translation_mm, rule.rotation_deg, rule.window_s, rule.max_time_s,
      static_cast<long long>(t.at_rest), static_cast<long long>(count), Median(t.resettle_s));
  std::printf(
      "stackgen-rest-check: parts that moved: %.1f %% (%lld) more than 1 mm or 1 deg "
      "(%.1f %% more than 1 mm, %.1f %% more than 1 deg), %.1f %% (%lld) more than 5 mm or "
      "10 deg; median %.2f mm and %.2f deg; the parts sank %.2f mm on average\n",
      Percent(t.moved, t.parts), static_cast<long long>(t.moved), Percent(t.shifted, t.parts),
      Percent(t.turned, t.parts), Percent(t.moved_far, t.parts),
      static_cast<long long>(t.moved_far), Median(t.shifts_mm), Median(t.turns_deg),
      t.parts > 0 ? t.sank_mm / t.parts : 0.0);
  std::printf("stackgen-rest-check: resting faces as published: %s\n",
              FaceShares(t.faces_before, several_types).c_str());
  std::printf("stackgen-rest-check: resting faces at strict rest: %s\n",
              FaceShares(t.faces_after, several_types).c_str());
}

int Run(int argc, char** argv) {
  std::string config_path = stackgen::DefaultConfigPath(STACKGEN_DEFAULT_CONFIG);
  int64_t count = 20, seed = 0;
  int generator_id = 0;
  std::string cache_dir = stackgen::DefaultCacheDir();
  stackgen::RestRule rule = stackgen::kStrictRestRule;
  stackgen::FlagParser parser("stackgen-rest-check");
  parser.String("--config", &config_path, "a config file");
  parser.Int("--count", &count, 1, 1000000);
  parser.Int("--seed", &seed, 0, INT64_MAX);
  parser.Int("--generator-id", &generator_id, 0, 65535);
  parser.String("--cache-dir", &cache_dir);
  using stackgen::Interval;
  parser.Double("--strict-mm", &rule.translation_mm, Interval::OpenClosed(0, 1e6));
  parser.Double("--strict-deg", &rule.rotation_deg, Interval::OpenClosed(0, 360));
  parser.Double("--strict-window-s", &rule.window_s, Interval::OpenClosed(0, 3600));
  parser.Double("--strict-max-s", &rule.max_time_s, Interval::OpenClosed(0, 1e5));
  parser.ParseOrExit(argc, argv, [] { std::printf("%s", kUsage); });
  if (rule.window_s > rule.max_time_s) {
    std::fprintf(stderr,
                 "stackgen-rest-check: error: --strict-window-s %g is longer than "
                 "--strict-max-s %g\n",
                 rule.window_s, rule.max_time_s);
    return 2;
  }

  const stackgen::LoadedConfig config = stackgen::LoadConfig(config_path);
  if (config.config.physics().drop_mode() == stackgen::config::PhysicsConfig::CUT_AND_PASTE) {
    std::fprintf(stderr,
                 "stackgen-rest-check: error: %s: physics.drop_mode CUT_AND_PASTE drops "
                 "nothing: there is no pile to check\n",
                 config.path.c_str());
    return 1;
  }
  const stackgen::SceneGenerator generator(config, generator_id, static_cast<uint64_t>(seed),
                                           cache_dir);
  const stackgen::PileSimulator& simulator = generator.simulator();
  const int types = config.config.part_size();
  Tally tally;
  tally.faces_before.resize(types);
  tally.faces_after.resize(types);
  stackgen::SettledPile pile;
  for (int64_t k = 0; k < count; ++k) {
    // the next pile as dropped (states after picks come from a fresh world: skipped)
    do {
      pile = pile.object_types.empty() && k == 0 ? generator.Settle(0) : generator.SettleNext(pile);
    } while (pile.level != 0);
    tally.physics_ms.push_back(pile.times.physics_ms);
    tally.redraws.Add(pile.times);
    // the same drop again, and on in the same world
    stackgen::PileResult again;
    const stackgen::PileResult published =
        simulator.Simulate(pile.object_types, std::mt19937_64(pile.drop_seed)(), rule, &again);
    for (size_t i = 0; i < pile.object_types.size(); ++i) {
      if (!published.world_from_object[i].isApprox(pile.world_from_object[i], 0)) {
        throw std::runtime_error("pile " + std::to_string(pile.pile) +
                                 ": its drop did not give the published pile again");
      }
    }
    Count(simulator, pile, again, &tally);
    std::fprintf(stderr, "\rstackgen-rest-check: pile %lld of %lld", static_cast<long long>(k + 1),
                 static_cast<long long>(count));
  }
  std::fprintf(stderr, "\n");

  std::printf("stackgen-rest-check: %s, seed %lld, generator %d: %lld piles, ", config.path.c_str(),
              static_cast<long long>(seed), generator_id, static_cast<long long>(count));
  Print(tally, rule, count, types > 1);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen-rest-check: error: %s\n", error.what());
    return 1;
  }
}
