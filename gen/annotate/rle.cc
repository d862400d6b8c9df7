#include "gen/annotate/rle.h"

#include <algorithm>
#include <cstring>
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

// The first nonzero byte in [p, end), or end; eight bytes at a time
const uint8_t* FirstNonZero(const uint8_t* p, const uint8_t* end) {
  for (uint64_t word = 0; end - p >= 8; p += 8) {
    std::memcpy(&word, p, 8);
    if (word != 0) break;
  }
  while (p < end && *p == 0) ++p;
  return p;
}

// One past the last nonzero byte in [begin, end), or begin
const uint8_t* EndOfNonZero(const uint8_t* begin, const uint8_t* end) {
  for (uint64_t word = 0; end - begin >= 8; end -= 8) {
    std::memcpy(&word, end - 8, 8);
    if (word != 0) break;
  }
  while (end > begin && end[-1] == 0) --end;
  return end;
}

// The box around the nonzero pixels of a CV_8UC1 mask; empty when there are none. (Not
// cv::boundingRect, which reads a mask of two columns as a list of points.)
cv::Rect NonZeroBox(const cv::Mat& mask) {
  int top = -1, bottom = -1, left = mask.cols, right = -1;
  for (int y = 0; y < mask.rows; ++y) {
    const uint8_t* row = mask.ptr<uint8_t>(y);
    const uint8_t* end = row + mask.cols;
    const uint8_t* first = FirstNonZero(row, end);
    if (first == end) continue;
    if (top < 0) top = y;
    bottom = y;
    left = std::min(left, static_cast<int>(first - row));
    right = std::max(right, static_cast<int>(EndOfNonZero(first, end) - row) - 1);
  }
  return top < 0 ? cv::Rect() : cv::Rect(left, top, right - left + 1, bottom - top + 1);
}

}  // namespace

std::vector<uint32_t> MaskToRuns(const cv::Mat& mask) {
  if (mask.type() != CV_8UC1) {
    throw std::runtime_error("MaskToRuns: mask must be CV_8UC1, got type " +
                             std::to_string(mask.type()));
  }
  // only the box around the set pixels is read (a part's mask covers a few percent of the
  // image); every pixel outside it is zero and joins the zeros run it falls in
  const cv::Rect box = NonZeroBox(mask);
  std::vector<uint32_t> runs;
  uint8_t previous = 0;
  uint64_t count = 0;
  const auto add_zeros = [&](uint64_t n) {
    if (n == 0) return;
    if (previous != 0) {
      runs.push_back(static_cast<uint32_t>(count));
      count = 0;
      previous = 0;
    }
    count += n;
  };
  const uint64_t height = static_cast<uint64_t>(mask.rows);
  add_zeros(static_cast<uint64_t>(box.x) * height);
  if (box.area() > 0) {
    // read column-major by walking the rows of the box's transpose
    cv::Mat columns;
    cv::transpose(mask(box), columns);
    const uint64_t below = height - static_cast<uint64_t>(box.y + box.height);
    for (int c = 0; c < columns.rows; ++c) {
      add_zeros(static_cast<uint64_t>(box.y));
      const uint8_t* pixel = columns.ptr<uint8_t>(c);
      for (int r = 0; r < columns.cols; ++r) {
        const uint8_t inside = pixel[r] != 0 ? 1 : 0;
        if (inside != previous) {
          runs.push_back(static_cast<uint32_t>(count));
          count = 0;
          previous = inside;
        }
        ++count;
      }
      add_zeros(below);
    }
  }
  add_zeros(static_cast<uint64_t>(mask.cols - box.x - box.width) * height);
  runs.push_back(static_cast<uint32_t>(count));
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
