// stackgen-stats: the posture statistics of one dataset, or the comparison of two, with plots.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "bus/flags.h"
#include "gen/annotate/pose.h"
#include "tools/stats/dataset.h"
#include "tools/stats/plots.h"
#include "tools/stats/statistics.h"

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
  stackgen::stats::ReadOptions read;
};

void PrintHelp() {
  std::printf(
      "Usage: %s DATASET_A [DATASET_B] --out DIR [--alpha A] [--frame CLASS=RZ,RY,RX]...\n"
      "                      [--class NAME] [--all-instances]\n"
      "\n"
      "The posture statistics of the instances of one dataset, or the comparison of two (the\n"
      "paper's Figure 3 and section 4). A dataset is a COCO file written by stackgen-coco (or its\n"
      "folder, holding annotations.json), or an LCM log recorded with lcm-logger holding\n"
      "STACKGEN_LABELS or STACKGEN_SCENE messages (a scene on both channels counts once); the\n"
      "kind is told by content.\n"
      "\n"
      "Each instance's posture is (alpha, beta, gamma), degrees, about the Z, Y, X axes of the\n"
      "bin frame: world_R_reference = Rz(alpha) Ry(beta) Rx(gamma). Its resting face is the\n"
      "index of the part's convex-hull face that points down (0 = largest face).\n"
      "\n"
      "With two datasets it prints one line per test, first:\n"
      "  alpha: D=<D> p=<p> same|different     two-sample Kolmogorov-Smirnov test per angle;\n"
      "  beta: ..., gamma: ...                 p exact when n1*n2 <= 10000, else asymptotic\n"
      "                                        (Kolmogorov distribution)\n"
      "  face: chi2=<x> dof=<k> p=<p> same|different\n"
      "                                        chi-square test of homogeneity of the resting\n"
      "                                        faces (faces no instance rests on dropped)\n"
      "  heading: V=<V> p=<p> same|different   the angle about the vertical (the turn left\n"
      "                                        after the tilt) by Kuiper's test: no +-180 wrap\n"
      "\"different\" means p < A: the hypothesis that both come from one distribution is\n"
      "rejected at significance A. Then the paper's D and Z (formula (4)) on samples it\n"
      "normalises (its p-values read the standard way), and the counts. With one dataset it\n"
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
      "                          every instance, from a COCO file its ignore regions (iscrowd\n"
      "                          1); a COCO file holds no dropped instances (default: annotated\n"
      "                          only, so a log and the COCO file of one run agree).\n"
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
  parser.ParseOrExit(argc, argv, PrintHelp);
  return flags;
}

// a number the way every line prints it
std::string Number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6g", value);
  return text;
}

const char* Verdict(double p, double significance) {
  return p < significance ? "different" : "same";
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
                     (dataset.kind == "COCO" ? " images" : " scenes");
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

void CompareTwo(const Dataset& a, const Dataset& b, const Flags& flags) {
  namespace stats = stackgen::stats;
  // the KS test per angle
  stats::KsMethod method = stats::KsMethod::kExact;
  for (const Angle& angle : kAngles) {
    const stats::KsResult result =
        stats::KolmogorovSmirnov2(Values(a.samples, angle.member), Values(b.samples, angle.member));
    method = result.method;
    std::printf("%s: D=%s p=%s %s\n", angle.name, Number(result.d).c_str(),
                Number(result.p).c_str(), Verdict(result.p, flags.significance));
  }

  // the chi-square test on the resting faces
  int64_t unknown_a = 0, unknown_b = 0;
  const std::vector<int64_t> faces_a = FaceCounts(a.samples, &unknown_a);
  const std::vector<int64_t> faces_b = FaceCounts(b.samples, &unknown_b);
  double min_expected = kMinExpectedCount;
  if (faces_a.empty() || faces_b.empty()) {
    std::printf("face: n/a (no resting faces known in %s)\n",
                faces_a.empty() ? (faces_b.empty() ? "A or B" : "A") : "B");
  } else {
    const stats::ChiSquareResult result = stats::ChiSquareHomogeneity(faces_a, faces_b);
    min_expected = result.min_expected;
    std::printf("face: chi2=%s dof=%d p=%s %s\n", Number(result.statistic).c_str(), result.dof,
                Number(result.p).c_str(), Verdict(result.p, flags.significance));
  }

  // the wrap-free comparison of the angle about the vertical
  const std::vector<double> heading_a = Values(a.samples, &PostureSample::heading_deg);
  const std::vector<double> heading_b = Values(b.samples, &PostureSample::heading_deg);
  if (!heading_a.empty() && !heading_b.empty()) {
    const stats::KuiperResult result = stats::Kuiper2(heading_a, heading_b);
    std::printf("heading: V=%s p=%s %s\n", Number(result.v).c_str(), Number(result.p).c_str(),
                Verdict(result.p, flags.significance));
  }

  // how to read the verdicts
  const std::string significance = Number(flags.significance);
  std::printf(
      "note: \"different\" means p < %s: the hypothesis that A and B come from one "
      "distribution is rejected\n",
      significance.c_str());
  std::printf("note: KS p-values %s, n1=%zu n2=%zu; face: chi-square test\n",
              method == stats::KsMethod::kExact ? "exact" : "asymptotic (Kolmogorov distribution)",
              a.samples.size(), b.samples.size());
  std::printf("note: heading: the angle about the vertical, by Kuiper's test (no +-180 wrap)\n");
  if (min_expected < kMinExpectedCount) {
    std::printf(
        "note: face: the smallest expected count is %s (< 5); the chi-square p-value is "
        "approximate\n",
        Number(min_expected).c_str());
  }

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
