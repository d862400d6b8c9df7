// The COCO RLE codec of contract/rle.h: the string form (RunsToString, StringToRuns) and the
// decoders every consumer uses, against the generator's OpenCV encoder (gen/annotate/rle.h).

#include "contract/rle.h"

#include <cstdint>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "gen/annotate/rle.h"

namespace stackgen {
namespace {

using Runs = std::vector<uint32_t>;

// Multi-char numbers and negative differences: runs 10 50 5 3 are ':' (10), 'b1' (50 = 18 + 1*32,
// chunk 18 has bit 0x10 so continues), '5', then 3-50 = -47 = 'aN' (chunks 17|0x20 and 30).
TEST(RleTest, MultiCharAndNegativeDifference) {
  const Runs runs = {10, 50, 5, 3};
  EXPECT_EQ(RunsToString(runs), ":b15aN");
  EXPECT_EQ(StringToRuns(":b15aN"), runs);
  EXPECT_EQ(RunsToString({100}), "T3");  // 100 = 4 + 3*32: 'T' = 48 + (4|0x20), '3'
  EXPECT_EQ(StringToRuns("T3"), (Runs{100}));
}

// Malformed strings throw: bad chars, a number cut short, too long, or a negative count.
TEST(RleTest, MalformedStringsThrow) {
  EXPECT_THROW(StringToRuns("1 2"), std::runtime_error);       // ' ' below '0'
  EXPECT_THROW(StringToRuns("1p"), std::runtime_error);        // 'p' above 'o'
  EXPECT_THROW(StringToRuns("1b"), std::runtime_error);        // 'b' says another char follows
  EXPECT_THROW(StringToRuns("ooooooo0"), std::runtime_error);  // 8 chars for one number
  EXPECT_THROW(StringToRuns("O"), std::runtime_error);         // -1 as the first count
  EXPECT_THROW(StringToRuns("11O"), std::runtime_error);       // third count -1 (no difference)
  EXPECT_EQ(StringToRuns("111O"), (Runs{1, 1, 1, 0}));         // fourth: 1 + (-1) = 0 is fine
}

// DecodeRleInto gives back, pixel for pixel, any mask the generator's encoder wrote
// (random blobs, empty, full, one pixel, masks whose runs wrap from column to column)
TEST(RleTest, DecodesWhatTheGeneratorEncodes) {
  std::mt19937 engine(7);
  for (int trial = 0; trial < 60; ++trial) {
    const int height = 1 + static_cast<int>(engine() % 90);
    const int width = 1 + static_cast<int>(engine() % 120);
    cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
    const int kind = trial % 4;
    if (kind == 1) mask.setTo(1);
    if (kind == 2) mask.at<uint8_t>(static_cast<int>(engine() % height), 0) = 1;
    if (kind == 3) {
      for (int blob = 0; blob < 4; ++blob) {
        cv::circle(mask, {static_cast<int>(engine() % width), static_cast<int>(engine() % height)},
                   static_cast<int>(engine() % 20), 1, cv::FILLED);
      }
    }
    const std::string counts = EncodeRle(mask);
    std::vector<uint8_t> decoded(static_cast<size_t>(height) * width, 0);
    const int64_t set = DecodeRleInto(counts, height, width, decoded.data());
    EXPECT_EQ(set, cv::countNonZero(mask));
    EXPECT_EQ(cv::countNonZero(cv::Mat(height, width, CV_8UC1, decoded.data()) != mask), 0)
        << "trial " << trial << " " << height << "x" << width;
  }
}

// strings that are no COCO RLE of the image are refused, never decoded past the buffer
TEST(RleTest, DecodeRefusesMalformedStrings) {
  std::vector<uint8_t> out(12, 0);
  for (const std::string& bad : {std::string("0~"), std::string("0"), std::string("="),
                                 EncodeRle(cv::Mat::ones(4, 4, CV_8UC1))}) {
    EXPECT_THROW(DecodeRleInto(bad, 3, 4, out.data()), std::runtime_error) << bad;
  }
}

// DecodeRleWindow sets the window's pixels as DecodeRleInto sets them in the whole image
TEST(RleTest, WindowIsACropOfTheWhole) {
  std::mt19937 engine(11);
  for (int trial = 0; trial < 40; ++trial) {
    const int height = 2 + static_cast<int>(engine() % 60);
    const int width = 2 + static_cast<int>(engine() % 60);
    cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
    cv::circle(mask, {static_cast<int>(engine() % width), static_cast<int>(engine() % height)},
               1 + static_cast<int>(engine() % 20), 1, cv::FILLED);
    const std::string counts = EncodeRle(mask);
    const int x0 = static_cast<int>(engine() % width), y0 = static_cast<int>(engine() % height);
    const int w = 1 + static_cast<int>(engine() % (width - x0));
    const int h = 1 + static_cast<int>(engine() % (height - y0));
    std::vector<uint8_t> window(static_cast<size_t>(w) * h, 0);
    const int64_t set = DecodeRleWindow(counts, height, width, x0, y0, w, h, window.data());
    const cv::Mat crop = mask(cv::Rect(x0, y0, w, h));
    EXPECT_EQ(set, cv::countNonZero(crop)) << "trial " << trial;
    EXPECT_EQ(cv::countNonZero(cv::Mat(h, w, CV_8UC1, window.data()) != crop), 0)
        << "trial " << trial;
  }
}

}  // namespace
}  // namespace stackgen
