#pragma once

// The figures of stackgen-stats, drawn with OpenCV (like the paper's Figure 3): posture scatter
// projections, histograms, cumulative frequencies and resting-face frequencies of one or two
// datasets.

#include <string>
#include <vector>

#include "research/stats/dataset.h"

namespace stackgen::stats {

/// One dataset in a figure.
struct PlotSeries {
  /// Legend text.
  std::string label;
  const std::vector<PostureSample>* samples = nullptr;
};

/// The file names WritePlots writes, in order.
std::vector<std::string> PlotFileNames();

/// Writes into `dir` (created if missing) the PNG figures of one or two series:
/// scatter_beta_alpha.png and scatter_beta_gamma.png (the 3D posture scatter projected on
/// (beta, alpha) and (beta, gamma)), histograms.png (alpha, beta, gamma in 36 bins of 10 degrees,
/// relative frequency), cumulative.png (the empirical CDFs of the three angles) and faces.png
/// (relative frequency of each resting face). Each file is written under a temporary name and
/// renamed, so a figure is never half-written. Returns the paths written. Throws
/// std::runtime_error naming the file or folder that cannot be written.
std::vector<std::string> WritePlots(const std::string& dir, const std::vector<PlotSeries>& series);

}  // namespace stackgen::stats
