#include "contract/rle.h"

#include <algorithm>
#include <limits>
#include <stdexcept>

namespace stackgen {
namespace {

// one number of the string form holds at most 7 chars (35 bits, enough for a signed difference
// of two uint32 counts)
constexpr int kMaxCharsPerNumber = 7;

}  // namespace

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

int64_t DecodeRleWindow(const std::string& counts, int height, int width, int x0, int y0,
                        int window_width, int window_height, uint8_t* out) {
  const std::vector<uint32_t> runs = StringToRuns(counts);
  const int64_t area = int64_t{height} * width;
  const int64_t x1 = int64_t{x0} + window_width, y1 = int64_t{y0} + window_height;
  int64_t position = 0, set = 0;
  for (size_t k = 0; k < runs.size(); ++k) {
    const int64_t end = position + runs[k];
    if (end > area) break;
    // a ones run, column by column: pixel p is row p % height of column p / height
    if (k % 2 == 1) {
      for (int64_t p = position; p < end;) {
        const int64_t column = p / height;
        const int64_t row = p % height;
        const int64_t rows = std::min<int64_t>(end - p, height - row);
        if (column >= x0 && column < x1) {
          const int64_t first = std::max<int64_t>(row, y0);
          const int64_t last = std::min<int64_t>(row + rows, y1);
          uint8_t* pixel = out + (first - y0) * window_width + (column - x0);
          for (int64_t r = first; r < last; ++r, pixel += window_width) *pixel = 1;
          set += std::max<int64_t>(0, last - first);
        }
        p += rows;
      }
    }
    position = end;
  }
  if (position != area) {
    throw std::runtime_error("the runs do not cover " + std::to_string(height) + "x" +
                             std::to_string(width) + " pixels");
  }
  return set;
}

int64_t DecodeRleInto(const std::string& counts, int height, int width, uint8_t* out) {
  return DecodeRleWindow(counts, height, width, 0, 0, width, height, out);
}

}  // namespace stackgen
