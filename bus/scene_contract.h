#pragma once

// The contract of a scene message that every consumer (and the generator) shares, so that no
// consumer keeps a copy of its own (design.md: consumers never include gen/, so it lives in bus/,
// which both may use): the id limits and the mask counts. The checks of the encoded images are
// in bounded_decode.h (CheckEncodedImageDims), the run-length parser in rle_counts.h.

#include <cstdint>
#include <string>

namespace stackgen {

/// The largest generator id (--generator-id is 0..65535).
inline constexpr int32_t kMaxGeneratorId = 65535;
/// The largest seq of a generator: image ids are generator_id * 10^9 + seq + 1 (COCO), and
/// 999999999 stays free.
inline constexpr int64_t kMaxSeq = 999999998;
/// The largest instance id: the instance map is uint16, 0 = background.
inline constexpr int32_t kMaxInstanceId = 65535;

/// True when a scene's ids fit the contract: generator_id 0..kMaxGeneratorId, seq 0..kMaxSeq.
inline bool SceneIdsInRange(int32_t generator_id, int64_t seq) {
  return generator_id >= 0 && generator_id <= kMaxGeneratorId && seq >= 0 && seq <= kMaxSeq;
}

/// The pixels set in a COCO compressed RLE mask (`counts`) of an image of `image_pixels` pixels.
/// Returns -1 and says why in `*why` (when not null; "is empty", "is not a COCO RLE string:
/// ...", "covers N pixels, the image has M") when the string is not such a mask.
int64_t MaskPixels(const std::string& counts, int64_t image_pixels, std::string* why);

}  // namespace stackgen
