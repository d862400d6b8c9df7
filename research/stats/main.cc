// stackgen-stats: the posture statistics of one dataset, or the comparison of two, with plots.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "cli/flags.h"
#include "consumers/bop/bop_dataset.h"
#include "gen/annotate/pose.h"
#include "research/stats/dataset.h"
#include "research/stats/piles.h"
#include "research/stats/plots.h"
#include "research/stats/statistics.h"

namespace {

namespace fs = std::filesystem;
using stackgen::stats::Dataset;
using stackgen::stats::PostureSample;

constexpr const char* kProgram = "stackgen-stats";
// the chi-square approximation wants at least this many expected instances per cell
constexpr double kMinExpectedCount = 5.0;
// characters of a dataset's path shown in a plot legend
constexpr size_t kMaxLegendPath = 40;

struct Flags {
  std::vector<std::string> datasets;
  std::string out;
  double significance = 0.05;
  int permutations = 999;
  int64_t seed = 1;
  int calibrate = 0;
  stackgen::stats::ReadOptions read;
};

void PrintHelp() {
  std::printf(
      "Usage: %s DATASET_A [DATASET_B] --out DIR [--alpha A] [--frame CLASS=RZ,RY,RX]...\n"
      "                      [--class NAME] [--all-instances] [--split NAME] [--permutations N]\n"
      "                      [--seed S] [--calibrate N] [--bus-key-file FILE | --open-bus]\n"
      "\n"
      "The pile and posture statistics of the instances of one dataset, or the comparison of two\n"
      "(the paper's Figure 3 and section 4, done so that it can tell piles apart). A dataset is a "
      "COCO file written by stackgen-coco (or its\n"
      "folder, holding annotations.json), a BOP dataset folder written by stackgen-bop (a folder\n"
      "without annotations.json that holds a split folder SPLIT/SCENE_ID/scene_gt.json), or an\n"
      "LCM log recorded with lcm-logger holding STACKGEN_LABELS or STACKGEN_SCENE messages (a\n"
      "scene on both channels counts once); the kind is told by content.\n"
      "\n"
      "From a BOP dataset it reads scene_gt.json (cam_R_m2c, cam_t_m2c, obj_id),\n"
      "scene_camera.json (cam_R_w2c, cam_t_w2c) and scene_gt_info.json (visib_fract) of every\n"
      "scene folder; each image is a scene. An instance's rotation in the bin frame is\n"
      "cam_R_w2c^T cam_R_m2c, its position cam_R_w2c^T (cam_t_m2c - cam_t_w2c). BOP has no\n"
      "annotated flag: a ground truth counts as annotated when visib_fract >= 0.3 (the\n"
      "generator's default annotation.min_visib_fract). Class names come from the categories\n"
      "of scene_gt_coco.json, else are obj_OBJ_ID (six digits, as models/obj_000001.ply). BOP\n"
      "has no resting faces.\n"
      "\n"
      "Each instance's posture is (alpha, beta, gamma), degrees, about the Z, Y, X axes of the\n"
      "bin frame: world_R_reference = Rz(alpha) Ry(beta) Rx(gamma). Its resting face is the\n"
      "index of the part's convex-hull face that points down (0 = largest face).\n"
      "\n"
      "With two datasets it prints one line per test, first:\n"
      "  alpha: D=<D> p=<p> holm=<q> same|different\n"
      "  beta: ..., gamma: ...                 Kolmogorov-Smirnov distance per posture angle\n"
      "  heading: V=<V> ...                    the angle about the vertical (the turn left\n"
      "                                        after the tilt), Kuiper's V: no +-180 wrap\n"
      "  face: chi2=<x> dof=<k> ...            chi-square of the resting faces (faces no\n"
      "                                        instance rests on dropped)\n"
      "  height: D=<D> ...                     z of each part's origin above the bin floor, mm\n"
      "  radius: D=<D> ...                     its distance from the bin's vertical centre\n"
      "                                        line, mm (height and radius need positions:\n"
      "                                        logs, COCO files with world_t_m2w)\n"
      "  verdict: same|different (K of M tests reject ...)\n"
      "The parts of one pile lie on each other and are not independent draws, so each p is a\n"
      "permutation p-value over whole piles: the share of N random reassignments of the\n"
      "piles of A and B to two groups of their sizes whose statistic is at least the observed\n"
      "one (a pile is a scene, or the scenes that share a part pose exactly: the views of one\n"
      "pile, physics.views_per_pile). holm is p corrected for the number of tests (Holm's "
      "step-down method); \"different\"\n"
      "means holm < A: the hypothesis that both come from one distribution is rejected, and two\n"
      "datasets of one config are called different by some test at most a share A of the time.\n"
      "Then the paper's D and Z (formula (4)) on samples it normalises (its p-values read the\n"
      "standard way, from the Kolmogorov distribution), and the counts. With one dataset it\n"
      "prints summaries of each angle (n, mean, sd, histogram peaks) and the face frequencies.\n"
      "It writes scatter_beta_alpha.png, scatter_beta_gamma.png, histograms.png, cumulative.png\n"
      "and faces.png into DIR.\n"
      "\n"
      "Options:\n"
      "  --out DIR               folder for the plots (required); created if missing, files in it\n"
      "                          with those names are replaced.\n"
      "  --alpha A               significance level of the tests, 0 < A < 1 (default 0.05).\n"
      "  --frame CLASS=RZ,RY,RX  the reference frame of class CLASS as a rotation in its object\n"
      "                          (mesh) frame, object_R_reference = Rz(RZ) Ry(RY) Rx(RX),\n"
      "                          degrees; posture = angles of world_R_object *\n"
      "                          object_R_reference. Repeat for several classes (default:\n"
      "                          the mesh frame; the built-in connector's mesh frame is the\n"
      "                          paper's: origin at the centre of its bottom plate, z up).\n"
      "                          Only the rotation matters: where the origin is changes no\n"
      "                          angle.\n"
      "  --class NAME            only instances of class NAME (default: all classes, pooled).\n"
      "  --all-instances         also instances that are not annotated (too hidden): from a log\n"
      "                          every instance, from a BOP dataset every ground truth, from a\n"
      "                          COCO file its ignore regions (iscrowd 1); a COCO file holds no\n"
      "                          dropped instances (default: annotated only, so a log and the\n"
      "                          COCO file of one run agree). Use it on logs and BOP datasets to\n"
      "                          compare whole piles, the bottom parts too.\n"
      "  --split NAME            the split folder of BOP datasets (default: train_pbr, else the\n"
      "                          only split folder there); other kinds ignore it.\n"
      "  --bus-key-file FILE     LCM logs: the bus key they were recorded under; messages not\n"
      "                          signed with it are left out (default: $STACKGEN_BUS_KEY_FILE,\n"
      "                          else this user's ~/.config/stackgen/bus.key).\n"
      "  --open-bus              LCM logs: check no key (a log recorded on an open bus).\n"
      "  --permutations N        random reassignments of whole piles per comparison, 19..1e6\n"
      "                          (default 999: p-values down to 0.001).\n"
      "  --seed S                seed of the permutations, >= 0 (default 1): the same seed, the\n"
      "                          same p-values.\n"
      "  --calibrate N           with one dataset: split its scenes at random into halves N\n"
      "                          times and compare the halves; prints how often the verdict is\n"
      "                          \"different\", a false alarm each time (at most A is expected).\n"
      "  --help                  print this help and exit.\n"
      "\n"
      "Exit status: 0 done (whatever the verdict), 1 the plots cannot be written, 2 bad command\n"
      "line or unreadable dataset.\n",
      kProgram);
}

// CLASS=RZ,RY,RX
void ParseFrame(const std::string& text, stackgen::stats::ReadOptions* read) {
  const size_t equals = text.rfind('=');
  if (equals == std::string::npos || equals == 0) {
    throw stackgen::UsageError("--frame wants CLASS=RZ,RY,RX, got \"" + text + "\"");
  }
  const std::string class_name = text.substr(0, equals);
  std::vector<double> angles;
  std::string rest = text.substr(equals + 1);
  for (size_t start = 0;;) {
    const size_t comma = rest.find(',', start);
    angles.push_back(stackgen::ParseNumber(
        "--frame " + class_name, rest.substr(start, comma - start), stackgen::Interval::All()));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  if (angles.size() != 3) {
    throw stackgen::UsageError("--frame wants three angles RZ,RY,RX for " + class_name +
                               ", got \"" + rest + "\"");
  }
  if (read->object_R_reference.count(class_name) != 0) {
    throw stackgen::UsageError("--frame given twice for class " + class_name);
  }
  read->object_R_reference[class_name] =
      stackgen::RotationFromPostureDeg(Eigen::Vector3d(angles[0], angles[1], angles[2]));
}

Flags ParseFlags(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  parser.Positional(&flags.datasets, "dataset", 1, 2);
  parser.String("--out", &flags.out, "a folder");
  parser.Require("--out");
  parser.Double("--alpha", &flags.significance, stackgen::Interval::Open(0, 1));
  parser.Custom("--frame", [&flags](const std::string& value) { ParseFrame(value, &flags.read); });
  parser.String("--class", &flags.read.class_name, "a class name");
  parser.Switch("--all-instances", &flags.read.all_instances);
  parser.String("--split", &flags.read.bop_split, "a folder name");
  parser.BusKey(&flags.read.bus_key_file, &flags.read.open_bus);
  parser.Int("--permutations", &flags.permutations, 19, 1000000);
  parser.Int("--seed", &flags.seed, 0, INT64_MAX);
  parser.Int("--calibrate", &flags.calibrate, 1, 100000);
  parser.ParseOrExit(argc, argv, PrintHelp, [&flags] {
    if (flags.calibrate > 0 && flags.datasets.size() != 1) {
      throw stackgen::UsageError("--calibrate takes one dataset, got " +
                                 std::to_string(flags.datasets.size()));
    }
  });
  return flags;
}

// a number the way every line prints it
std::string Number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

std::vector<double> Values(const std::vector<PostureSample>& samples,
                           double PostureSample::*angle) {
  std::vector<double> values;
  for (const PostureSample& sample : samples) {
    if (!std::isnan(sample.*angle)) values.push_back(sample.*angle);
  }
  return values;
}

// instances per resting face (index = face); unknown faces counted in `unknown`
std::vector<int64_t> FaceCounts(const std::vector<PostureSample>& samples, int64_t* unknown) {
  std::vector<int64_t> counts;
  *unknown = 0;
  for (const PostureSample& sample : samples) {
    if (sample.resting_face < 0) {
      ++*unknown;
      continue;
    }
    if (static_cast<size_t>(sample.resting_face) >= counts.size()) {
      counts.resize(sample.resting_face + 1, 0);
    }
    ++counts[sample.resting_face];
  }
  return counts;
}

struct Angle {
  const char* name;
  double PostureSample::*member;
};
const Angle kAngles[] = {{"alpha", &PostureSample::alpha_deg},
                         {"beta", &PostureSample::beta_deg},
                         {"gamma", &PostureSample::gamma_deg}};

// "A: path (COCO): 1234 instances of 100 images" and the notes that go with it
void PrintDatasetLine(const char* letter, const Dataset& dataset, const Flags& flags) {
  std::string line = std::string(letter) + ": " + dataset.path + " (" + dataset.kind +
                     "): " + std::to_string(dataset.samples.size()) + " instances of " +
                     std::to_string(dataset.scenes) +
                     (dataset.kind == "LCM log" ? " scenes" : " images");
  // views of one pile (scenes sharing part poses) count as one pile in the tests
  int64_t scenes_used = 0;
  {
    std::set<int64_t> scenes;
    for (const PostureSample& sample : dataset.samples) scenes.insert(sample.scene);
    scenes_used = static_cast<int64_t>(scenes.size());
  }
  if (dataset.piles < scenes_used) {
    line +=
        " (" + std::to_string(dataset.piles) + " piles: views of one pile are permuted together)";
  }
  if (dataset.not_annotated > 0) {
    line += ", " + std::to_string(dataset.not_annotated) + " not annotated left out";
  }
  if (dataset.other_class > 0) {
    line += ", " + std::to_string(dataset.other_class) + " of other classes left out";
  }
  if (dataset.truncated_bytes > 0) {
    line += ", an incomplete last event (" + std::to_string(dataset.truncated_bytes) +
            " bytes) ignored";
  }
  if (dataset.repeated_scenes > 0) {
    line += ", " + std::to_string(dataset.repeated_scenes) + " repeated scene messages skipped";
  }
  std::printf("%s\n", line.c_str());
  if (dataset.class_counts.size() > 1) {
    std::string classes;
    for (const auto& [name, count] : dataset.class_counts) {
      classes += (classes.empty() ? "" : ", ") + name + " " + std::to_string(count);
    }
    std::printf("note: %s pools %zu classes (%s); --class NAME compares one\n", letter,
                dataset.class_counts.size(), classes.c_str());
  }
  if (dataset.kind == "BOP") {
    const std::string used = flags.read.all_instances
                                 ? "every ground truth is used"
                                 : "a ground truth counts as annotated when its visib_fract >= " +
                                       Number(stackgen::kBopMinVisibFract) +
                                       " (the generator's default annotation.min_visib_fract)";
    std::printf("note: %s is a BOP dataset (split %s): %s; its images are the scenes\n", letter,
                dataset.split.c_str(), used.c_str());
  }
  if (flags.read.all_instances && dataset.kind == "COCO") {
    std::printf(
        "note: %s is a COCO file: --all-instances adds its ignore regions (iscrowd 1), but "
        "instances the generator dropped are not in it\n",
        letter);
  }
}

// the local maxima of a 36-bin histogram of (-180, 180], tallest first, at most three, as bin
// centres; `circular` joins the first and last bin
std::string HistogramPeaks(const std::vector<double>& values, bool circular) {
  std::vector<int64_t> counts(36, 0);
  for (const double value : values) {
    ++counts[std::clamp(static_cast<int>(std::floor((value + 180.0) / 10.0)), 0, 35)];
  }
  std::vector<std::pair<int64_t, int>> peaks;
  for (int bin = 0; bin < 36; ++bin) {
    const int before = bin - 1, after = bin + 1;
    const int64_t left = before >= 0 ? counts[before] : (circular ? counts[35] : 0);
    const int64_t right = after < 36 ? counts[after] : (circular ? counts[0] : 0);
    if (counts[bin] > 0 && counts[bin] > left && counts[bin] >= right) {
      peaks.emplace_back(counts[bin], bin);
    }
  }
  std::sort(peaks.begin(), peaks.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  std::string text;
  for (size_t k = 0; k < peaks.size() && k < 3; ++k) {
    text += (k == 0 ? "" : ",") + Number(-175.0 + 10.0 * peaks[k].second);
  }
  return text.empty() ? "none" : text;
}

// the face table: "face 0: 123 (45.1%) 110 (44.0%)" per face, unknown last
void PrintFaceTable(const std::vector<const Dataset*>& datasets) {
  std::vector<std::vector<int64_t>> counts;
  std::vector<int64_t> unknown(datasets.size(), 0);
  size_t faces = 0;
  for (size_t d = 0; d < datasets.size(); ++d) {
    counts.push_back(FaceCounts(datasets[d]->samples, &unknown[d]));
    faces = std::max(faces, counts.back().size());
  }
  const auto share = [&](int64_t count, size_t d) {
    char text[48];
    std::snprintf(text, sizeof(text), " %6lld (%5.1f%%)", static_cast<long long>(count),
                  100.0 * count / std::max<double>(1.0, datasets[d]->samples.size()));
    return std::string(text);
  };
  std::printf("resting faces (instances, share of the dataset):\n%s\n",
              datasets.size() == 2 ? "                A               B" : "                A");
  for (size_t face = 0; face < faces; ++face) {
    char label[32];
    std::snprintf(label, sizeof(label), "  face %2zu:", face);
    std::string line = label;
    for (size_t d = 0; d < datasets.size(); ++d) {
      line += share(face < counts[d].size() ? counts[d][face] : 0, d);
    }
    std::printf("%s\n", line.c_str());
  }
  if (std::any_of(unknown.begin(), unknown.end(), [](int64_t n) { return n > 0; })) {
    std::string line = "   unknown:";
    for (size_t d = 0; d < datasets.size(); ++d) line += share(unknown[d], d);
    std::printf("%s\n", line.c_str());
  }
}

// the pile tests of A against B: one line per test, then the verdict
stackgen::stats::PileComparison ComparePiles(const Dataset& a, const Dataset& b,
                                             const Flags& flags) {
  stackgen::stats::PileOptions options;
  options.permutations = flags.permutations;
  options.seed = static_cast<uint64_t>(flags.seed);
  options.significance = flags.significance;
  return stackgen::stats::ComparePiles(a, b, options);
}

void CompareTwo(const Dataset& a, const Dataset& b, const Flags& flags) {
  namespace stats = stackgen::stats;
  // the tests, each by permuting whole piles, corrected for their number
  const stats::PileComparison comparison = ComparePiles(a, b, flags);
  int rejected = 0;
  for (const stats::PileTest& test : comparison.tests) {
    const std::string dof = test.statistic == "chi2" ? " dof=" + std::to_string(test.dof) : "";
    std::printf("%s: %s=%s%s p=%s holm=%s %s\n", test.name.c_str(), test.statistic.c_str(),
                Number(test.value).c_str(), dof.c_str(), Number(test.p).c_str(),
                Number(test.p_holm).c_str(), test.different ? "different" : "same");
    rejected += test.different ? 1 : 0;
  }
  const std::string significance = Number(flags.significance);
  std::printf("verdict: %s (%d of %zu tests reject at %s after Holm's correction)\n",
              comparison.different ? "different" : "same", rejected, comparison.tests.size(),
              significance.c_str());
  for (const std::string& left_out : comparison.left_out) {
    std::printf("note: %s, not tested\n", left_out.c_str());
  }

  // how to read the verdicts
  std::printf(
      "note: p: the share of %d random reassignments of whole piles (%lld of A, %lld of B) "
      "whose\nnote: statistic is at least as large (seed %lld); the parts of one pile are not\n"
      "note: independent, so piles, not parts, are permuted\n",
      flags.permutations, static_cast<long long>(comparison.piles_a),
      static_cast<long long>(comparison.piles_b), static_cast<long long>(flags.seed));
  std::printf(
      "note: holm: p corrected for the %zu tests (Holm); \"different\" means holm < %s: the\n"
      "note: hypothesis that A and B come from one distribution is rejected, and two datasets of\n"
      "note: one config get \"different\" from some test at most %s of the time\n",
      comparison.tests.size(), significance.c_str(), significance.c_str());
  std::printf(
      "note: D: Kolmogorov-Smirnov distance; heading (the angle about the vertical): Kuiper's V,\n"
      "note: no +-180 wrap; face: chi-square of the resting faces; height: z of a part's origin\n"
      "note: above the bin floor, radius: its distance from the bin's vertical centre line, mm\n");

  // the paper's procedure, for reproducing its table
  std::printf(
      "note: the paper's procedure: each sample min-max normalised, then standardised;\n"
      "note: Z = D*sqrt(n1*n2/(n1+n2)) (formula (4)), p = Q_KS(Z)\n");
  for (const Angle& angle : kAngles) {
    const stats::PaperKsResult result =
        stats::PaperKs(Values(a.samples, angle.member), Values(b.samples, angle.member));
    std::printf("paper %s: D=%s Z=%s p=%s\n", angle.name, Number(result.d).c_str(),
                Number(result.z).c_str(), Number(result.p).c_str());
  }
  std::printf(
      "note: the paper reads p-values like its 6.4e-11, 2.7e-10 and 0.0082 as \"no "
      "significant\nnote: difference\"; below %s they mean the opposite\n",
      significance.c_str());
}

void SummariseOne(const Dataset& dataset) {
  namespace stats = stackgen::stats;
  for (const Angle& angle : kAngles) {
    const std::vector<double> values = Values(dataset.samples, angle.member);
    double mean = 0.0, squares = 0.0;
    for (const double value : values) mean += value;
    mean /= static_cast<double>(values.size());
    for (const double value : values) squares += (value - mean) * (value - mean);
    const double sd = values.size() > 1 ? std::sqrt(squares / (values.size() - 1.0)) : 0.0;
    const auto [low, high] = std::minmax_element(values.begin(), values.end());
    std::printf("%s: n=%zu mean=%s sd=%s min=%s max=%s peaks=%s\n", angle.name, values.size(),
                Number(mean).c_str(), Number(sd).c_str(), Number(*low).c_str(),
                Number(*high).c_str(),
                HistogramPeaks(values, angle.member != &PostureSample::beta_deg).c_str());
  }
  // the angle about the vertical: circular mean and resultant length
  const std::vector<double> heading = Values(dataset.samples, &PostureSample::heading_deg);
  if (!heading.empty()) {
    double c = 0.0, s = 0.0;
    for (const double value : heading) {
      c += std::cos(value * M_PI / 180.0);
      s += std::sin(value * M_PI / 180.0);
    }
    const double length = std::hypot(c, s) / static_cast<double>(heading.size());
    std::printf(
        "heading: n=%zu circular mean=%s resultant length=%s (0: spread evenly, 1: all "
        "alike)\n",
        heading.size(), Number(std::atan2(s, c) * 180.0 / M_PI).c_str(), Number(length).c_str());
  }
  int64_t unknown = 0;
  const std::vector<int64_t> faces = FaceCounts(dataset.samples, &unknown);
  std::string line = "face:";
  for (size_t face = 0; face < faces.size(); ++face) {
    line += " " + std::to_string(face) + ":" + std::to_string(faces[face]);
  }
  if (unknown > 0) line += " unknown:" + std::to_string(unknown);
  std::printf("%s\n", line.c_str());
}

// the Wilson score interval (95 %) of a rate of `k` in `n`
std::pair<double, double> WilsonInterval(int64_t k, int64_t n) {
  const double z = 1.959963984540054, p = static_cast<double>(k) / n;
  const double centre = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
  const double half = z * std::sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)) / (1.0 + z * z / n);
  return {std::max(0.0, centre - half), std::min(1.0, centre + half)};
}

// how often the pile tests call two halves of one dataset "different": its scenes split at
// random into halves `flags.calibrate` times. With the scenes independent draws of one config
// that is a false alarm each time, which should happen at most at the significance level.
void Calibrate(const Dataset& dataset, const Flags& flags) {
  // whole piles go to one half (the views of one pile are not independent)
  std::map<int64_t, int64_t> pile_of_scene;
  for (const PostureSample& sample : dataset.samples) pile_of_scene[sample.scene] = sample.pile;
  std::vector<int64_t> piles;
  for (const auto& [scene, pile] : pile_of_scene) piles.push_back(pile);
  std::sort(piles.begin(), piles.end());
  piles.erase(std::unique(piles.begin(), piles.end()), piles.end());
  if (piles.size() < 4) {
    throw std::runtime_error(dataset.path +
                             ": --calibrate needs at least 4 piles with parts, it has " +
                             std::to_string(piles.size()));
  }
  std::mt19937_64 engine(static_cast<uint64_t>(flags.seed));
  std::map<std::string, int64_t> rejected_by_test;
  std::vector<std::string> names;
  int64_t rejected = 0;
  auto last_progress = std::chrono::steady_clock::now();
  for (int split = 0; split < flags.calibrate; ++split) {
    std::shuffle(piles.begin(), piles.end(), engine);
    const std::set<int64_t> first_piles(piles.begin(), piles.begin() + piles.size() / 2);
    std::vector<bool> first(static_cast<size_t>(dataset.scenes), false);
    for (const auto& [scene, pile] : pile_of_scene) first[scene] = first_piles.count(pile) != 0;
    const auto [one, other] = stackgen::stats::SplitScenes(dataset, first);
    Flags split_flags = flags;
    split_flags.seed =
        static_cast<int64_t>((static_cast<uint64_t>(flags.seed) + 1 + split) & INT64_MAX);
    const stackgen::stats::PileComparison comparison = ComparePiles(one, other, split_flags);
    rejected += comparison.different ? 1 : 0;
    for (const stackgen::stats::PileTest& test : comparison.tests) {
      if (rejected_by_test.count(test.name) == 0) names.push_back(test.name);
      rejected_by_test[test.name] += test.different ? 1 : 0;
    }
    // a progress line on long runs
    const auto now = std::chrono::steady_clock::now();
    if (now - last_progress > std::chrono::seconds(5)) {
      std::fprintf(stderr, "%s: calibrating: %d of %d splits, %lld different\n", kProgram,
                   split + 1, flags.calibrate, static_cast<long long>(rejected));
      last_progress = now;
    }
  }
  const auto [low, high] = WilsonInterval(rejected, flags.calibrate);
  std::printf(
      "calibration: %d random splits of the %zu piles into halves: \"different\" in %lld "
      "(%.1f%%, 95%% interval %.1f..%.1f%%); at most %s%% are expected\n",
      flags.calibrate, piles.size(), static_cast<long long>(rejected),
      100.0 * rejected / flags.calibrate, 100.0 * low, 100.0 * high,
      Number(100.0 * flags.significance).c_str());
  std::string line = "calibration per test (different):";
  for (const std::string& name : names) {
    line += " " + name + " " + std::to_string(rejected_by_test[name]);
  }
  std::printf("%s\n", line.c_str());
}

int Run(const Flags& flags) {
  // read the datasets; any fault in them is an input error
  std::vector<Dataset> datasets;
  for (const std::string& path : flags.datasets) {
    try {
      datasets.push_back(stackgen::stats::ReadDataset(path, flags.read));
    } catch (const std::exception& error) {
      std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
      return 2;
    }
    if (datasets.back().samples.empty()) {
      const std::string of_class =
          flags.read.class_name.empty() ? "" : " of class " + flags.read.class_name;
      std::fprintf(stderr, "%s: error: %s holds no instances%s\n", kProgram, path.c_str(),
                   of_class.c_str());
      return 2;
    }
  }

  // the tests (two datasets) or the summary (one)
  if (datasets.size() == 2) {
    CompareTwo(datasets[0], datasets[1], flags);
  } else {
    if (flags.calibrate > 0) {
      try {
        Calibrate(datasets[0], flags);
      } catch (const std::runtime_error& error) {
        std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
        return 2;
      }
    }
    SummariseOne(datasets[0]);
  }
  const char* letters[] = {"A", "B"};
  std::vector<const Dataset*> pointers;
  for (size_t d = 0; d < datasets.size(); ++d) {
    PrintDatasetLine(letters[d], datasets[d], flags);
    pointers.push_back(&datasets[d]);
  }
  for (const auto& [class_name, unused] : flags.read.object_R_reference) {
    if (std::none_of(datasets.begin(), datasets.end(), [&](const Dataset& dataset) {
          return dataset.class_counts.count(class_name) != 0;
        })) {
      std::printf("note: --frame names class %s, which no instance used has\n", class_name.c_str());
    }
  }
  PrintFaceTable(pointers);

  // the figures
  std::vector<stackgen::stats::PlotSeries> series;
  for (size_t d = 0; d < datasets.size(); ++d) {
    // the path as given, its end when it is long
    std::string name = datasets[d].path;
    if (name.size() > kMaxLegendPath) name = "..." + name.substr(name.size() - kMaxLegendPath);
    series.push_back({std::string(letters[d]) + ": " + name +
                          " (n=" + std::to_string(datasets[d].samples.size()) + ")",
                      &datasets[d].samples});
  }
  const std::vector<std::string> written = stackgen::stats::WritePlots(flags.out, series);
  std::string line = "plots:";
  for (const std::string& path : written) line += " " + path;
  std::printf("%s\n", line.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  try {
    return Run(flags);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
    return 1;
  }
}
