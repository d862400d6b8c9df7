#include "gen/annotate/rle.h"

#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

using Runs = std::vector<uint32_t>;
using Box = std::array<int, 4>;

// a CV_8UC1 mask from rows of 0/1
cv::Mat MaskFromRows(const std::vector<std::vector<int>>& rows) {
  cv::Mat mask(static_cast<int>(rows.size()), static_cast<int>(rows[0].size()), CV_8UC1);
  for (int y = 0; y < mask.rows; ++y) {
    for (int x = 0; x < mask.cols; ++x) mask.at<uint8_t>(y, x) = rows[y][x] ? 255 : 0;
  }
  return mask;
}

bool SameMask(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

// A 3x3 mask: column-major pixels 0 1 0 | 1 1 0 | 0 0 1 give runs 1 1 1 2 3 1; the string stores
// 1 1 1, then 2-1 = 1, 3-1 = 2, 1-2 = -1 ('O' = 48 + 31: the low 5 bits of -1, sign bit set).
TEST(RleTest, ThreeByThreeHandComputed) {
  const cv::Mat mask = MaskFromRows({{0, 1, 0}, {1, 1, 0}, {0, 0, 1}});
  const Runs runs = MaskToRuns(mask);
  EXPECT_EQ(runs, (Runs{1, 1, 1, 2, 3, 1}));
  EXPECT_EQ(RunsToString(runs), "11112O");
  EXPECT_EQ(EncodeRle(mask), "11112O");
  EXPECT_EQ(StringToRuns("11112O"), runs);
  EXPECT_TRUE(SameMask(DecodeRle("11112O", 3, 3), mask));
  EXPECT_EQ(RleArea("11112O"), 4u);
  EXPECT_EQ(RleBbox("11112O", 3, 3), (Box{0, 0, 3, 3}));
}

// A mask whose first (column-major) pixel is set starts with a zeros run of 0.
TEST(RleTest, FirstPixelSetStartsWithZeroRun) {
  // columns (1,1) and (0,1): pixels 1 1 0 1, runs 0 2 1 1; string 0 2 1 then 1-2 = -1 -> 'O'
  const cv::Mat mask = MaskFromRows({{1, 0}, {1, 1}});
  EXPECT_EQ(MaskToRuns(mask), (Runs{0, 2, 1, 1}));
  EXPECT_EQ(EncodeRle(mask), "021O");
  EXPECT_TRUE(SameMask(DecodeRle("021O", 2, 2), mask));
  EXPECT_EQ(RleArea("021O"), 3u);
  EXPECT_EQ(RleBbox("021O", 2, 2), (Box{0, 0, 2, 2}));
}

// An empty 4x5 mask is one zeros run of 20 = 0b10100: chunk 20 has bit 0x10 set, so a second
// chunk 0 follows ('d' = 48 + 20 + 0x20, then '0').
TEST(RleTest, EmptyMask) {
  const cv::Mat mask = cv::Mat::zeros(4, 5, CV_8UC1);
  EXPECT_EQ(MaskToRuns(mask), (Runs{20}));
  EXPECT_EQ(EncodeRle(mask), "d0");
  EXPECT_TRUE(SameMask(DecodeRle("d0", 4, 5), mask));
  EXPECT_EQ(RleArea("d0"), 0u);
  EXPECT_EQ(RleBbox("d0", 4, 5), (Box{0, 0, 0, 0}));
}

// A full 4x5 mask is runs 0 20: "0d0"; its box is the whole image.
TEST(RleTest, FullMask) {
  const cv::Mat mask(4, 5, CV_8UC1, cv::Scalar(1));
  EXPECT_EQ(MaskToRuns(mask), (Runs{0, 20}));
  EXPECT_EQ(EncodeRle(mask), "0d0");
  EXPECT_TRUE(SameMask(DecodeRle("0d0", 4, 5), mask * 255));
  EXPECT_EQ(RleArea("0d0"), 20u);
  EXPECT_EQ(RleBbox("0d0", 4, 5), (Box{0, 0, 5, 4}));
}

// A box spans the full height when a ones run wraps from one column into the next (rleToBbox).
TEST(RleTest, BboxOfRunWrappingColumns) {
  // 4 rows x 3 cols, column-major pixels: 0 0 0 1 | 1 0 0 0 | 0 0 0 0
  const cv::Mat mask = MaskFromRows({{0, 1, 0}, {0, 0, 0}, {0, 0, 0}, {1, 0, 0}});
  EXPECT_EQ(MaskToRuns(mask), (Runs{3, 2, 7}));
  EXPECT_EQ(RleBbox(EncodeRle(mask), 4, 3), (Box{0, 0, 2, 4}));
  // a single pixel at (x 2, y 1) of a 3x4 image
  cv::Mat one = cv::Mat::zeros(3, 4, CV_8UC1);
  one.at<uint8_t>(1, 2) = 7;
  EXPECT_EQ(MaskToRuns(one), (Runs{7, 1, 4}));
  EXPECT_EQ(RleBbox(EncodeRle(one), 3, 4), (Box{2, 1, 1, 1}));
}

// Random masks survive mask -> string -> mask; area and box agree with OpenCV (fixed seed).
TEST(RleTest, RandomRoundTrips) {
  std::mt19937 engine(1234);
  for (int trial = 0; trial < 200; ++trial) {
    const int height = 1 + static_cast<int>(engine() % 40);
    const int width = 1 + static_cast<int>(engine() % 40);
    cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
    // a few filled rectangles
    const int rectangles = static_cast<int>(engine() % 4);
    for (int r = 0; r < rectangles; ++r) {
      const int x = static_cast<int>(engine() % width), y = static_cast<int>(engine() % height);
      const int w = 1 + static_cast<int>(engine() % (width - x));
      const int h = 1 + static_cast<int>(engine() % (height - y));
      mask(cv::Rect(x, y, w, h)).setTo(255);
    }
    const std::string counts = EncodeRle(mask);
    ASSERT_TRUE(SameMask(DecodeRle(counts, height, width), mask)) << counts;
    EXPECT_EQ(RleArea(counts), static_cast<uint64_t>(cv::countNonZero(mask)));
    const cv::Rect rect = cv::boundingRect(mask);
    const Box tight = rect.area() ? Box{rect.x, rect.y, rect.width, rect.height} : Box{};
    const Box box = RleBbox(counts, height, width);
    if (rectangles <= 1) {
      // one rectangle: its runs never wrap a column unless it spans the full height
      EXPECT_EQ(box, tight) << counts;
    } else {
      // runs that wrap columns widen the box to the full height, never the x range
      EXPECT_EQ(box[0], tight[0]);
      EXPECT_EQ(box[2], tight[2]);
      EXPECT_LE(box[1], tight[1]);
      EXPECT_GE(box[1] + box[3], tight[1] + tight[3]);
    }
  }
}

// The runs of every pixel read column by column, as cocoapi's rleEncode: what MaskToRuns, which
// reads only the box around the set pixels, must give.
Runs RunsOfEveryPixel(const cv::Mat& mask) {
  Runs runs;
  uint8_t previous = 0;
  uint32_t count = 0;
  for (int x = 0; x < mask.cols; ++x) {
    for (int y = 0; y < mask.rows; ++y) {
      const uint8_t inside = mask.at<uint8_t>(y, x) != 0 ? 1 : 0;
      if (inside != previous) {
        runs.push_back(count);
        count = 0;
        previous = inside;
      }
      ++count;
    }
  }
  runs.push_back(count);
  return runs;
}

// Scattered pixels, set pixels on the first and last rows and columns, all-zero masks and views
// into a larger image (rows not contiguous) give the runs of every pixel (fixed seed).
TEST(RleTest, RunsOfTheBoxAreThoseOfEveryPixel) {
  std::mt19937 engine(99);
  for (int trial = 0; trial < 300; ++trial) {
    const int height = 1 + static_cast<int>(engine() % 30);
    const int width = 1 + static_cast<int>(engine() % 30);
    cv::Mat whole = cv::Mat::zeros(height + 4, width + 6, CV_8UC1);
    cv::Mat mask = whole(cv::Rect(3, 2, width, height));
    const int pixels = static_cast<int>(engine() % 8);  // 0: an all-zero mask
    for (int p = 0; p < pixels; ++p) {
      int x = static_cast<int>(engine() % width), y = static_cast<int>(engine() % height);
      if (engine() % 4 == 0) x = engine() % 2 ? 0 : width - 1;   // on a first or last column
      if (engine() % 4 == 0) y = engine() % 2 ? 0 : height - 1;  // on a first or last row
      mask.at<uint8_t>(y, x) = static_cast<uint8_t>(1 + engine() % 255);
    }
    if (engine() % 5 == 0) mask.row(static_cast<int>(engine() % height)).setTo(7);
    whole.row(0).setTo(255);  // outside the view: never read
    ASSERT_EQ(MaskToRuns(mask), RunsOfEveryPixel(mask))
        << height << " x " << width << ", " << pixels << " pixels, trial " << trial;
  }
}

// Runs that do not cover height * width are refused when decoding.
TEST(RleTest, WrongSizeThrows) {
  EXPECT_THROW(DecodeRle("11112O", 3, 4), std::runtime_error);
  EXPECT_THROW(RleBbox("11112O", 2, 3), std::runtime_error);
  EXPECT_THROW(MaskToRuns(cv::Mat::zeros(2, 2, CV_16UC1)), std::runtime_error);
  EXPECT_EQ(StringToRuns(""), Runs{});
}

}  // namespace
}  // namespace stackgen
