#include "bus/rle_counts.h"

#include <limits>
#include <stdexcept>

namespace stackgen {

std::vector<uint32_t> ParseRleCounts(const std::string& counts) {
  std::vector<uint32_t> runs;
  size_t p = 0;
  while (p < counts.size()) {
    int64_t x = 0;
    int k = 0;
    bool more = true;
    while (more) {
      if (p >= counts.size()) throw std::runtime_error("a number is cut short");
      if (k >= 7) throw std::runtime_error("a number runs past 7 characters");
      const int c = static_cast<unsigned char>(counts[p]) - 48;
      if (c < 0 || c > 63) throw std::runtime_error("a char outside '0'..'o'");
      x |= static_cast<int64_t>(c & 0x1f) << (5 * k);
      more = (c & 0x20) != 0;
      ++p;
      ++k;
      if (!more && (c & 0x10)) x -= int64_t{1} << (5 * k);
    }
    if (runs.size() > 2) x += runs[runs.size() - 2];
    if (x < 0 || x > std::numeric_limits<uint32_t>::max()) {
      throw std::runtime_error("a count outside 0..2^32-1");
    }
    runs.push_back(static_cast<uint32_t>(x));
  }
  return runs;
}

}  // namespace stackgen
