#pragma once

// The masks of the instance message (mask_visib_rle, mask_obj_rle) as consumers read them.
// Consumers do not link gen/, whose gen/annotate/rle.h writes these strings; this is the one
// reader they share.

#include <cstdint>
#include <string>
#include <vector>

namespace stackgen {

/// The runs of a COCO compressed RLE string (cocoapi maskApi.c rleFrString: 5 bits per char,
/// '0'..'o', counts from the third on stored as the difference to the one two before), starting
/// with a run of zeros. Throws std::runtime_error naming the fault on a malformed string.
std::vector<uint32_t> ParseRleCounts(const std::string& counts);

}  // namespace stackgen
