#pragma once

// Test helper: compares a rendered image with a stored golden image.

#include <gtest/gtest.h>

#include <cstdlib>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

namespace stackgen {
namespace testing {

/// Checks that `bgr` (CV_8UC3, BGR) matches tests/fixtures/`fixture` within a tolerance for
/// renderers that differ a little in shading and on edges: mean gray difference < 1.5 and under
/// 1 % of the pixels off by more than 24. On failure it writes `<name>_diff.png` (difference x 4)
/// and `<name>_actual.png` into the test temp folder and names them. STACKGEN_UPDATE_GOLDEN=1
/// rewrites the golden image first.
inline void ExpectMatchesGolden(const cv::Mat& bgr, const std::string& fixture,
                                const std::string& name) {
  const std::string golden_path = std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/" + fixture;
  const char* update = std::getenv("STACKGEN_UPDATE_GOLDEN");
  if (update != nullptr && std::string(update) == "1") {
    ASSERT_TRUE(cv::imwrite(golden_path, bgr)) << golden_path;
  }
  const cv::Mat golden = cv::imread(golden_path, cv::IMREAD_COLOR);
  ASSERT_FALSE(golden.empty()) << "cannot read " << golden_path;
  ASSERT_EQ(golden.size(), bgr.size()) << golden_path;

  // tolerance: mean difference and the share of pixels far off
  cv::Mat diff;
  cv::absdiff(bgr, golden, diff);
  cv::Mat diff_gray;
  cv::cvtColor(diff, diff_gray, cv::COLOR_BGR2GRAY);
  const double mean_diff = cv::mean(diff_gray)[0];
  const int large_diffs = cv::countNonZero(diff_gray > 24);
  if (!(mean_diff < 1.5 && large_diffs < static_cast<int>(bgr.total() / 100))) {
    const std::string diff_path = ::testing::TempDir() + name + "_diff.png";
    const std::string actual_path = ::testing::TempDir() + name + "_actual.png";
    cv::imwrite(diff_path, diff * 4);
    cv::imwrite(actual_path, bgr);
    ADD_FAILURE() << "image differs from " << golden_path << ": mean " << mean_diff << ", "
                  << large_diffs << " pixels off by > 24; diff image " << diff_path
                  << ", actual image " << actual_path;
  }
}

}  // namespace testing
}  // namespace stackgen
