#pragma once

// The contract of a scene message that every consumer (and the generator) shares, so that no
// consumer keeps a copy of its own (docs/design.md, "Layout": consumers never include gen/, so
// it lives in bus/, which both may use): the id limits, the mask counts and CheckScene, which a
// consumer runs once on every scene that comes off the bus. The checks of the encoded image headers
// are in bounded_decode.h (CheckEncodedImageDims), the run-length codec in rle.h.

#include <cstdint>
#include <string>

#include <stackgen/scene.hpp>

namespace stackgen {

/// The largest generator id (--generator-id is 0..65535).
inline constexpr int32_t kMaxGeneratorId = 65535;
/// The largest seq of a generator (10^8 - 2: 58 days of 20 scenes/s): COCO image ids are
/// generator_id * 10^8 + seq + 1 and annotation ids image id * 1000 + instance, so every id of
/// every allowed scene stays below 2^53 (a double, JavaScript's and jq's numbers, holds it
/// exactly), and 99999999 stays free.
inline constexpr int64_t kMaxSeq = 99999998;
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

/// The most mask pixels one scene may hold (instances x width x height, 4 Gi): a consumer that
/// decodes every full mask needs that much memory.
inline constexpr int64_t kMaxSceneMaskPixels = int64_t{1} << 32;

/// Checks that a scene agrees with itself, as every consumer needs before it uses one; returns
/// false with one line in `*why` (when not null) naming the field at fault and the values:
/// - header: generator_id and seq within the limits above;
/// - camera: a positive size within DecodeLimits::max_image_pixels, fx, fy and depth_scale_mm
///   positive and finite, cx, cy and world_from_camera finite;
/// - images: colour present (RGB8 or GRAY8), depth (DEPTH16) and instance map (INSTANCE16)
///   checked when present; each of the camera's size, its size field equal to its bytes, RAW,
///   PNG or JPEG, RAW of width * height * bytes per pixel, a PNG or JPEG header that declares
///   that size and format (CheckEncodedImageDims; the image is not decoded);
/// - instances: num_instances equal to their number, at most kMaxSceneMaskPixels mask pixels;
///   each with an instance_id in 1..kMaxInstanceId used once, class_id >= 1, a class_name,
///   finite poses and posture, visib_fract in [0, 1], 0 <= px_count_visib <= px_count_all,
///   bbox_visib inside the image and bbox_obj reaching past it by at most the image's size each
///   way, masks (MaskPixels) over the image holding px_count_visib and px_count_all pixels (at
///   most px_count_all when bbox_obj reaches outside the image), not both annotated and ignored,
///   and visible pixels when either.
bool CheckScene(const scene& message, std::string* why);

}  // namespace stackgen
