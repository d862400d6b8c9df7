#include "gen/annotate/rle.h"

#include <algorithm>
#include <limits>
#include <stdexcept>

namespace stackgen {
namespace {

// one number of the string form holds at most 7 chars (35 bits, enough for a signed difference
// of two uint32 counts)
constexpr int kMaxCharsPerNumber = 7;

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

std::string RunsToString(const std::vector<uint32_t>& runs) {
  std::string text;
  text.reserve(runs.size() * 2);
  for (size_t i = 0; i < runs.size(); ++i) {
    // from the fourth count on, store the difference to the count two before
    int64_t x = runs[i];
    if (i > 2) x -= static_cast<int64_t>(runs[i - 2]);
    // 5 bits per char, low bits first; bit 0x20 says another char follows
    bool more = true;
    while (more) {
      int c = static_cast<int>(x & 0x1f);
      x >>= 5;  // arithmetic shift: negative differences keep their sign
      more = (c & 0x10) ? x != -1 : x != 0;
      if (more) c |= 0x20;
      text.push_back(static_cast<char>(c + 48));
    }
  }
  return text;
}

std::vector<uint32_t> StringToRuns(const std::string& counts) {
  std::vector<uint32_t> runs;
  size_t p = 0;
  while (p < counts.size()) {
    const size_t start = p;
    // gather 5-bit chunks until one without the continuation bit
    int64_t x = 0;
    int k = 0;
    bool more = true;
    while (more) {
      if (p >= counts.size()) {
        throw std::runtime_error("RLE string ends inside the number that starts at offset " +
                                 std::to_string(start));
      }
      if (k >= kMaxCharsPerNumber) {
        throw std::runtime_error("RLE string has a number of more than " +
                                 std::to_string(kMaxCharsPerNumber) + " chars at offset " +
                                 std::to_string(start));
      }
      const int ch = static_cast<unsigned char>(counts[p]);
      if (ch < 48 || ch > 111) {
        throw std::runtime_error("RLE string has char code " + std::to_string(ch) + " at offset " +
                                 std::to_string(p) + ", expected '0'..'o'");
      }
      const int c = ch - 48;
      x |= static_cast<int64_t>(c & 0x1f) << (5 * k);
      more = (c & 0x20) != 0;
      ++p;
      ++k;
      // sign-extend a negative number
      if (!more && (c & 0x10)) x |= static_cast<int64_t>(-1) * (int64_t{1} << (5 * k));
    }
    // undo the difference to the count two before
    if (runs.size() > 2) x += static_cast<int64_t>(runs[runs.size() - 2]);
    if (x < 0 || x > static_cast<int64_t>(std::numeric_limits<uint32_t>::max())) {
      throw std::runtime_error("RLE string gives count " + std::to_string(x) + " at offset " +
                               std::to_string(start) + ", outside 0..2^32-1");
    }
    runs.push_back(static_cast<uint32_t>(x));
  }
  return runs;
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
