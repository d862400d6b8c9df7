#include "gen/annotate/rle.h"

#include <algorithm>
#include <stdexcept>

namespace stackgen {
namespace {

uint64_t SumRuns(const std::vector<uint32_t>& runs) {
  uint64_t sum = 0;
  for (const uint32_t run : runs) sum += run;
  return sum;
}

void CheckRunsCover(const std::vector<uint32_t>& runs, int height, int width, const char* what) {
  if (height < 0 || width < 0) {
    throw std::runtime_error(std::string(what) + ": negative mask size " + std::to_string(height) +
                             " x " + std::to_string(width));
  }
  const uint64_t sum = SumRuns(runs);
  const uint64_t area = static_cast<uint64_t>(height) * static_cast<uint64_t>(width);
  if (sum != area) {
    throw std::runtime_error(std::string(what) + ": RLE runs add up to " + std::to_string(sum) +
                             " pixels, expected height * width = " + std::to_string(height) +
                             " * " + std::to_string(width) + " = " + std::to_string(area));
  }
}

}  // namespace

std::vector<uint32_t> MaskToRuns(const cv::Mat& mask) {
  if (mask.type() != CV_8UC1) {
    throw std::runtime_error("MaskToRuns: mask must be CV_8UC1, got type " +
                             std::to_string(mask.type()));
  }
  // read column-major by walking the rows of the transpose
  cv::Mat columns;
  if (!mask.empty()) cv::transpose(mask, columns);
  std::vector<uint32_t> runs;
  uint8_t previous = 0;
  uint32_t count = 0;
  for (int c = 0; c < columns.rows; ++c) {
    const uint8_t* pixel = columns.ptr<uint8_t>(c);
    for (int r = 0; r < columns.cols; ++r) {
      const uint8_t inside = pixel[r] != 0 ? 1 : 0;
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

cv::Mat RunsToMask(const std::vector<uint32_t>& runs, int height, int width) {
  CheckRunsCover(runs, height, width, "RunsToMask");
  // fill the transpose row by row (= the mask column by column), then transpose back
  cv::Mat columns(width, height, CV_8UC1);
  uint8_t* pixel = columns.data;  // continuous: freshly allocated
  uint8_t value = 0;
  for (const uint32_t run : runs) {
    std::fill(pixel, pixel + run, value);
    pixel += run;
    value = value != 0 ? 0 : 255;
  }
  cv::Mat mask(height, width, CV_8UC1);
  if (height > 0 && width > 0) cv::transpose(columns, mask);
  return mask;
}

std::string EncodeRle(const cv::Mat& mask) { return RunsToString(MaskToRuns(mask)); }

cv::Mat DecodeRle(const std::string& counts, int height, int width) {
  return RunsToMask(StringToRuns(counts), height, width);
}

uint64_t RleArea(const std::string& counts) {
  const std::vector<uint32_t> runs = StringToRuns(counts);
  uint64_t area = 0;
  for (size_t i = 1; i < runs.size(); i += 2) area += runs[i];
  return area;
}

std::array<int, 4> RunsBbox(const std::vector<uint32_t>& runs, int height, int width) {
  CheckRunsCover(runs, height, width, "RunsBbox");
  // only whole (zeros, ones) pairs count; a trailing zeros run adds nothing
  const size_t m = runs.size() / 2 * 2;
  if (m == 0 || height == 0 || width == 0) return {0, 0, 0, 0};
  // as rleToBbox: track the first and last pixel of every ones run, uint arithmetic
  const uint32_t h = static_cast<uint32_t>(height);
  uint32_t xs = static_cast<uint32_t>(width), ys = h, xe = 0, ye = 0, cc = 0, xp = 0;
  for (size_t j = 0; j < m; ++j) {
    cc += runs[j];
    const uint32_t t = cc - static_cast<uint32_t>(j % 2);
    const uint32_t y = t % h;
    const uint32_t x = (t - y) / h;
    if (j % 2 == 0) {
      xp = x;
    } else if (xp < x) {
      // the run wraps into a later column: it covers the full height
      ys = 0;
      ye = h - 1;
    }
    xs = std::min(xs, x);
    xe = std::max(xe, x);
    ys = std::min(ys, y);
    ye = std::max(ye, y);
  }
  return {static_cast<int>(xs), static_cast<int>(ys), static_cast<int>(xe - xs + 1),
          static_cast<int>(ye - ys + 1)};
}

std::array<int, 4> RleBbox(const std::string& counts, int height, int width) {
  return RunsBbox(StringToRuns(counts), height, width);
}

}  // namespace stackgen
