#include "bus/scene_contract.h"

#include <stdexcept>
#include <vector>

#include "bus/rle_counts.h"

namespace stackgen {

int64_t MaskPixels(const std::string& counts, int64_t image_pixels, std::string* why) {
  const auto refuse = [why](const std::string& text) -> int64_t {
    if (why != nullptr) *why = text;
    return -1;
  };
  if (counts.empty()) return refuse("is empty");
  std::vector<uint32_t> runs;
  try {
    runs = ParseRleCounts(counts);
  } catch (const std::runtime_error& error) {
    return refuse(std::string("is not a COCO RLE string: ") + error.what());
  }
  // runs alternate, starting with the background
  int64_t total = 0, inside = 0;
  for (size_t k = 0; k < runs.size(); ++k) {
    total += runs[k];
    if (k % 2 == 1) inside += runs[k];
  }
  if (total != image_pixels) {
    return refuse("covers " + std::to_string(total) + " pixels, the image has " +
                  std::to_string(image_pixels));
  }
  return inside;
}

}  // namespace stackgen
