#pragma once

// Decoding of received LCM messages that a bad message cannot crash or blow up: a message of
// another type, a truncated or corrupt payload (another program on the shared host, a fuzzer)
// is refused with a one-line reason, and decoding never allocates much more than the message's
// own size, which is itself capped.

#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <utility>
#include <vector>

namespace stackgen {

// the lcm-gen classes with variable-length arrays, which have their own bounded decoder
class image;
class labels;
class model;
class resend_request;
class scene;

/// Limits on what decoding one received message may allocate.
struct DecodeLimits {
  /// Messages larger than this are refused before decoding (bytes). Default 256 MiB.
  size_t max_message_bytes = size_t{256} << 20;
  /// Images with more pixels than this (width * height) are refused. Default 64 Mpx.
  int64_t max_image_pixels = int64_t{64} << 20;
  /// Instances per scene/labels message above this are refused. Default 65535.
  int32_t max_instances = 65535;
  /// Suction grasps, and parallel-jaw grasps, per scene/labels message above this are refused.
  /// Default 1,048,576 of each.
  int32_t max_grasps = 1 << 20;
  /// Vertices per model message above this are refused (triangles: twice as many). Default
  /// 4,000,000.
  int32_t max_model_vertices = 4000000;
};

namespace internal {

/// Bytes of the fingerprint that starts every LCM message.
inline constexpr size_t kFingerprintBytes = 8;

/// Where the strings of an lcm-gen type without variable-length arrays are, found from the
/// encoding of a value-initialised message: every number encodes as zeros and every string as
/// the length 1 and a NUL, so each 0x01 byte ends a string's length field.
struct StringLayout {
  /// The encoded size with every string empty (no fingerprint): the smallest there is.
  int64_t min_size = 0;
  /// The offset of each string's int32 length field in that encoding, ascending.
  std::vector<int64_t> length_offsets;
  /// False when the encoding did not look like that (then every message is refused).
  bool valid = false;
};

/// The StringLayout of the encoding `empty` of a value-initialised message.
StringLayout FindStringLayout(const std::vector<uint8_t>& empty);

/// The StringLayout of `Struct`, found once.
template <typename Struct>
const StringLayout& StringLayoutOf() {
  static const StringLayout layout = [] {
    const Struct empty{};
    std::vector<uint8_t> bytes(static_cast<size_t>(empty._getEncodedSizeNoHash()));
    empty._encodeNoHash(bytes.data(), 0, static_cast<int>(bytes.size()));
    return FindStringLayout(bytes);
  }();
  return layout;
}

/// Walks one encoded struct of `layout` at data[0, size) (no fingerprint), checking each string
/// length (at least 1, within the data, a NUL at the end and none inside) before the generated
/// decoder trusts it. Returns the bytes the struct spans, or -1 with a reason naming `what` in
/// `*why` (when not null).
int64_t CheckStrings(const uint8_t* data, size_t size, const StringLayout& layout,
                     const std::string& what, std::string* why);

/// Checks `size` against the limits and the leading fingerprint against `hash`; on failure sets
/// `*why` (when not null) and returns false. `type_name` is Message::getTypeName().
bool CheckEnvelope(const uint8_t* data, size_t size, const DecodeLimits& limits, int64_t hash,
                   const char* type_name, std::string* why);

/// Checks that the message body (after the fingerprint) spans exactly the rest of the `size`
/// bytes: `spanned` < 0 means it did not decode. On failure sets `*why` and returns false.
bool CheckSpan(int64_t spanned, size_t size, const char* type_name, std::string* why);

/// Sets `*why` (when not null) to `reason` and returns false.
bool Refuse(std::string reason, std::string* why);

}  // namespace internal

/// Decodes `size` bytes as `Message` into `*out` without allocating more than the limits and
/// the message's own size allow. Returns true on success; false with a one-line reason in
/// `*why` (when not null; e.g. "wrong type (fingerprint 0x... is stackgen.status, not
/// stackgen.scene)", "num_instances 2147483647 needs at least ... bytes, 1200 remain", "color
/// image 70000x70000 exceeds max_image_pixels (67108864)", "color.size 123 != width*height*3
/// (144) for a RAW RGB8 image", "message of 300000000 bytes exceeds max_message_bytes
/// (268435456)"), and `*out` unchanged. Bytes left over after the message are refused too, and
/// strings that LCM would not write (no NUL at the end, one inside). Never throws for bad input.
///
/// Images (scene color, depth, instance_map, depth_sensor; an image message): width and height
/// >= 0, width *
/// height <= max_image_pixels, pixel_format and encoding known values; size 0 is accepted as "no
/// image" (whatever the encoding). With data: width and height > 0, pixel_format and encoding
/// not INVALID, RAW size == width * height * bytes per pixel (3, 1, 2, 2), PNG and JPEG size <=
/// twice that + 4096, JPEG only for RGB8 and GRAY8. The data itself is not looked at: call
/// CheckEncodedImageDims before decoding a PNG or JPEG.
///
/// This generic version checks the size and the fingerprint, then every string length (see
/// StringLayout), then runs the generated decoder. It is for types without variable-length
/// arrays, whose generated decoders size the array from the count before checking the bytes
/// remain; every stackgen type with one (scene, labels, image, resend_request, model) has a
/// specialisation below that checks each count against the bytes that remain and the limits
/// before anything is allocated.
template <typename Message>
bool DecodeBounded(const uint8_t* data, size_t size, const DecodeLimits& limits, Message* out,
                   std::string* why) {
  // the size and the fingerprint, then the strings, before anything is decoded
  const char* type_name = Message::getTypeName();
  if (!internal::CheckEnvelope(data, size, limits, Message::getHash(), type_name, why)) {
    return false;
  }
  const size_t body = size - internal::kFingerprintBytes;
  const int64_t spanned = internal::CheckStrings(data + internal::kFingerprintBytes, body,
                                                 internal::StringLayoutOf<Message>(),
                                                 std::string("stackgen.") + type_name, why);
  if (spanned < 0 || !internal::CheckSpan(spanned, size, type_name, why)) return false;
  // the generated decoder, into a copy so that `*out` is untouched on failure
  try {
    Message message{};
    const int decoded = message._decodeNoHash(data, static_cast<int>(internal::kFingerprintBytes),
                                              static_cast<int>(body));
    if (!internal::CheckSpan(decoded, size, type_name, why)) return false;
    *out = std::move(message);
    return true;
  } catch (const std::exception& error) {
    return internal::Refuse(
        std::string("cannot decode stackgen.") + type_name + ": " + error.what(), why);
  }
}

template <>
bool DecodeBounded<scene>(const uint8_t* data, size_t size, const DecodeLimits& limits, scene* out,
                          std::string* why);
template <>
bool DecodeBounded<labels>(const uint8_t* data, size_t size, const DecodeLimits& limits,
                           labels* out, std::string* why);
template <>
bool DecodeBounded<image>(const uint8_t* data, size_t size, const DecodeLimits& limits, image* out,
                          std::string* why);
template <>
bool DecodeBounded<resend_request>(const uint8_t* data, size_t size, const DecodeLimits& limits,
                                   resend_request* out, std::string* why);
template <>
bool DecodeBounded<model>(const uint8_t* data, size_t size, const DecodeLimits& limits, model* out,
                          std::string* why);

/// Checks, without decoding, that a PNG or JPEG image holds what its fields declare: the PNG
/// IHDR or the first JPEG SOFn marker must give width x height, and the bit depth and channels
/// of pixel_format (PNG: 8-bit RGB or gray, 16-bit gray; JPEG: 8-bit, 3 or 1 components). Call
/// it before cv::imdecode, which sizes its output from the file header, not from the message: a
/// small message can hold a PNG that claims 60000 x 60000 pixels. A RAW image passes when its
/// size is width * height * bytes per pixel; an image with no data passes (nothing to decode).
/// Assumes an image that DecodeBounded accepted (width * height already limited). Returns false
/// with a one-line reason in `*why` (when not null). Never throws for bad input.
bool CheckEncodedImageDims(const image& image, std::string* why);

}  // namespace stackgen
