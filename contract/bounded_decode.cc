#include "contract/bounded_decode.h"

#include <climits>
#include <cstdio>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include <lcm/lcm_coretypes.h>
#include <stackgen/camera_info.hpp>
#include <stackgen/config_text.hpp>
#include <stackgen/credit.hpp>
#include <stackgen/header.hpp>
#include <stackgen/image.hpp>
#include <stackgen/instance.hpp>
#include <stackgen/jaw_grasp.hpp>
#include <stackgen/suction_grasp.hpp>
#include <stackgen/labels.hpp>
#include <stackgen/model.hpp>
#include <stackgen/pose.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

namespace stackgen {
namespace internal {

namespace {

// "0x9dad6b486d12784a" for a fingerprint.
std::string Hex(int64_t value) {
  char text[24];
  std::snprintf(text, sizeof(text), "0x%016llx",
                static_cast<unsigned long long>(static_cast<uint64_t>(value)));
  return text;
}

// the stackgen type whose fingerprint is `hash`, or nullptr when it is none of ours.
const char* KnownTypeOf(int64_t hash) {
  static const std::pair<int64_t, const char*> kTypes[] = {
      {camera_info::getHash(), "camera_info"},
      {config_text::getHash(), "config_text"},
      {credit::getHash(), "credit"},
      {header::getHash(), "header"},
      {image::getHash(), "image"},
      {instance::getHash(), "instance"},
      {labels::getHash(), "labels"},
      {model::getHash(), "model"},
      {pose::getHash(), "pose"},
      {resend_request::getHash(), "resend_request"},
      {scene::getHash(), "scene"},
      {status::getHash(), "status"},
      {suction_grasp::getHash(), "suction_grasp"},
      {jaw_grasp::getHash(), "jaw_grasp"}};
  for (const auto& [type_hash, name] : kTypes) {
    if (type_hash == hash) return name;
  }
  return nullptr;
}

}  // namespace

bool Refuse(std::string reason, std::string* why) {
  if (why != nullptr) *why = std::move(reason);
  return false;
}

bool CheckEnvelope(const uint8_t* data, size_t size, const DecodeLimits& limits, int64_t hash,
                   const char* type_name, std::string* why) {
  // the size, before anything is read
  const std::string bytes = "message of " + std::to_string(size) + " bytes";
  if (size > limits.max_message_bytes) {
    return Refuse(
        bytes + " exceeds max_message_bytes (" + std::to_string(limits.max_message_bytes) + ")",
        why);
  }
  if (size > static_cast<size_t>(INT_MAX)) {
    return Refuse(bytes + " is larger than LCM can encode", why);
  }
  if (size < kFingerprintBytes)
    return Refuse(bytes + " is shorter than the 8-byte fingerprint", why);
  if (data == nullptr) return Refuse(bytes + " without data", why);
  // the fingerprint: a message of another type is named, not decoded
  int64_t fingerprint = 0;
  __int64_t_decode_array(data, 0, static_cast<int>(kFingerprintBytes), &fingerprint, 1);
  if (fingerprint != hash) {
    const char* known = KnownTypeOf(fingerprint);
    return Refuse("wrong type (fingerprint " + Hex(fingerprint) +
                      (known != nullptr ? std::string(" is stackgen.") + known + ", not"
                                        : std::string(" is not")) +
                      " stackgen." + type_name + ")",
                  why);
  }
  return true;
}

bool CheckSpan(int64_t spanned, size_t size, const char* type_name, std::string* why) {
  const std::string what = std::string("stackgen.") + type_name;
  if (spanned < 0) {
    return Refuse(
        "cannot decode " + std::to_string(size) + " bytes as " + what + " (truncated or corrupt)",
        why);
  }
  const uint64_t used = kFingerprintBytes + static_cast<uint64_t>(spanned);
  if (used != size) {
    return Refuse(std::to_string(size - used) + " bytes left over after a " + what + " of " +
                      std::to_string(used) + " bytes",
                  why);
  }
  return true;
}

StringLayout FindStringLayout(const std::vector<uint8_t>& empty) {
  // each string is 00 00 00 01 00 (length 1, a NUL); no number encodes a 0x01 byte when 0
  StringLayout layout;
  layout.min_size = static_cast<int64_t>(empty.size());
  layout.valid = true;
  for (size_t i = 0; i < empty.size(); ++i) {
    if (empty[i] == 0) continue;
    const bool length_one = empty[i] == 1 && i >= 3 && i + 1 < empty.size() && empty[i - 3] == 0 &&
                            empty[i - 2] == 0 && empty[i - 1] == 0 && empty[i + 1] == 0;
    if (!length_one) {
      layout.valid = false;
      break;
    }
    layout.length_offsets.push_back(static_cast<int64_t>(i) - 3);
  }
  return layout;
}

int64_t CheckStrings(const uint8_t* data, size_t size, const StringLayout& layout,
                     const std::string& what, std::string* why) {
  if (!layout.valid) {
    Refuse(what + " has a layout bounded decoding does not know (see StringLayout)", why);
    return -1;
  }
  // `at` walks the received bytes, `empty_at` the encoding with empty strings beside it
  const int64_t available = static_cast<int64_t>(size);
  int64_t at = 0;
  int64_t empty_at = 0;
  const auto truncated = [&](int64_t needed) {
    Refuse(what + " needs at least " + std::to_string(needed) + " bytes, " +
               std::to_string(available) + " remain",
           why);
    return int64_t{-1};
  };
  for (size_t k = 0; k < layout.length_offsets.size(); ++k) {
    // the numbers before string k, then its length
    at += layout.length_offsets[k] - empty_at;
    empty_at = layout.length_offsets[k] + 5;
    if (at + 4 > available) return truncated(at + 4 + (layout.min_size - empty_at) + 1);
    int32_t length = 0;
    __int32_t_decode_array(data, static_cast<int>(at), 4, &length, 1);
    at += 4;
    const std::string field = what + " string " + std::to_string(k + 1) + " of " +
                              std::to_string(layout.length_offsets.size()) + " (byte " +
                              std::to_string(at - 4) + ")";
    if (length < 1) {
      Refuse(field + " has length " + std::to_string(length) +
                 ", not positive (it counts the terminating NUL)",
             why);
      return -1;
    }
    if (length > available - at) {
      Refuse(field + " has length " + std::to_string(length) + ", " +
                 std::to_string(available - at) + " bytes remain",
             why);
      return -1;
    }
    // a NUL at the end and none inside: what LCM writes, and what re-encodes to the same bytes
    const char* text = reinterpret_cast<const char*>(data + at);
    if (text[length - 1] != '\0') {
      Refuse(field + " does not end with a NUL", why);
      return -1;
    }
    if (std::memchr(text, '\0', static_cast<size_t>(length - 1)) != nullptr) {
      Refuse(field + " has a NUL inside", why);
      return -1;
    }
    at += length;
  }
  // the numbers after the last string
  at += layout.min_size - empty_at;
  if (at > available) return truncated(at);
  return at;
}

}  // namespace internal

namespace {

using internal::kFingerprintBytes;

// a cursor over a received message that mirrors the generated decoders field by field, but
// checks every length against the bytes that remain (and the limits) before it allocates; the
// first failure is kept as a one-line reason naming the field.
class Reader {
 public:
  Reader(const uint8_t* data, size_t size, const DecodeLimits& limits)
      : data_(data),
        size_(static_cast<int>(size)),
        pos_(static_cast<int>(kFingerprintBytes)),
        limits_(limits) {}

  // names the fields read while it lives as `prefix` + field ("instances[2].class_name").
  class Scope {
   public:
    Scope(Reader& reader, const std::string& prefix)
        : reader_(reader), saved_(reader.prefix_.size()) {
      reader_.prefix_ += prefix;
    }
    ~Scope() { reader_.prefix_.resize(saved_); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    Reader& reader_;
    const size_t saved_;
  };

  int position() const { return pos_; }
  int remaining() const { return size_ - pos_; }
  const DecodeLimits& limits() const { return limits_; }
  const std::string& reason() const { return reason_; }
  // the full name of `field` in the current scope.
  std::string Name(const char* field) const { return prefix_ + field; }

  // keeps `reason` and returns false.
  bool Fail(std::string reason) {
    reason_ = std::move(reason);
    return false;
  }

  // `count` primitives through the LCM decoder `decode` (__int32_t_decode_array, ...).
  template <typename T>
  bool Primitives(const char* field, int (*decode)(const void*, int, int, T*, int), T* values,
                  int count) {
    const int used = decode(data_, pos_, remaining(), values, count);
    if (used < 0) return Truncated(field, static_cast<int64_t>(sizeof(T)) * count);
    pos_ += used;
    return true;
  }

  // a struct without variable-length arrays: its strings checked, then its generated decoder.
  template <typename Type>
  bool Struct(const char* field, Type* value) {
    std::string why;
    const int64_t spanned =
        internal::CheckStrings(data_ + pos_, static_cast<size_t>(remaining()),
                               internal::StringLayoutOf<Type>(), Name(field), &why);
    if (spanned < 0) return Fail(std::move(why));
    const int used = value->_decodeNoHash(data_, pos_, static_cast<int>(spanned));
    if (used != spanned) return Fail(Name(field) + " does not decode");
    pos_ += used;
    return true;
  }

  // an LCM string: int32 length including the terminating NUL, then the bytes; checked as
  // CheckStrings checks the strings of a struct.
  bool String(const char* field, std::string* value) {
    int32_t length = 0;
    if (!Primitives(field, __int32_t_decode_array, &length, 1)) return false;
    const std::string text = Name(field) + " length " + std::to_string(length);
    if (length < 1) return Fail(text + " is not positive (it counts the terminating NUL)");
    if (length > remaining()) {
      return Fail(text + " needs " + std::to_string(length) + " bytes, " +
                  std::to_string(remaining()) + " remain");
    }
    const char* bytes = reinterpret_cast<const char*>(data_ + pos_);
    if (bytes[length - 1] != '\0') return Fail(Name(field) + " does not end with a NUL");
    if (std::memchr(bytes, '\0', static_cast<size_t>(length - 1)) != nullptr) {
      return Fail(Name(field) + " has a NUL inside");
    }
    value->assign(bytes, static_cast<size_t>(length - 1));
    pos_ += length;
    return true;
  }

  // `count` raw bytes; the caller has checked count against remaining().
  bool Bytes(const char* field, int32_t count, std::vector<uint8_t>* value) {
    if (count < 0 || count > remaining()) return Truncated(field, count);
    value->assign(data_ + pos_, data_ + pos_ + count);
    pos_ += count;
    return true;
  }

  // a count of array elements of at least `min_element_bytes` each, checked against the bytes
  // that remain and then against `max` (the limit `limit_name`).
  bool Count(const char* field, int32_t count, int64_t min_element_bytes, int64_t max,
             const char* limit_name) {
    const std::string text = Name(field) + " " + std::to_string(count);
    if (count < 0) return Fail(text + " is negative");
    const int64_t needed = count * min_element_bytes;
    if (needed > remaining()) {
      return Fail(text + " needs at least " + std::to_string(needed) + " bytes, " +
                  std::to_string(remaining()) + " remain");
    }
    if (count > max) {
      return Fail(text + " exceeds " + limit_name + " (" + std::to_string(max) + ")");
    }
    return true;
  }

 private:
  bool Truncated(const char* field, int64_t needed) {
    return Fail(Name(field) + " needs " + std::to_string(needed) + " bytes, " +
                std::to_string(remaining()) + " remain");
  }

  const uint8_t* const data_;
  const int size_;
  int pos_;
  const DecodeLimits& limits_;
  std::string prefix_;
  std::string reason_;
};

// bytes per pixel of a RAW image of `pixel_format`; 0 for an invalid or unknown format.
int BytesPerPixel(int8_t pixel_format) {
  switch (pixel_format) {
    case image::PIXEL_RGB8:
      return 3;
    case image::PIXEL_GRAY8:
      return 1;
    case image::PIXEL_DEPTH16:
    case image::PIXEL_INSTANCE16:
      return 2;
    default:
      return 0;
  }
}

const char* PixelFormatName(int8_t pixel_format) {
  switch (pixel_format) {
    case image::PIXEL_RGB8:
      return "RGB8";
    case image::PIXEL_GRAY8:
      return "GRAY8";
    case image::PIXEL_DEPTH16:
      return "DEPTH16";
    case image::PIXEL_INSTANCE16:
      return "INSTANCE16";
    default:
      return "INVALID";
  }
}

const char* EncodingName(int8_t encoding) {
  switch (encoding) {
    case image::ENCODING_RAW:
      return "RAW";
    case image::ENCODING_PNG:
      return "PNG";
    case image::ENCODING_JPEG:
      return "JPEG";
    default:
      return "INVALID";
  }
}

// what is wrong with the fields of image `name` read so far (all but data), with `remaining`
// bytes left for its data; empty when nothing is.
std::string ImageProblem(const std::string& name, const image& m, int remaining,
                         const DecodeLimits& limits) {
  const std::string dims = std::to_string(m.width) + "x" + std::to_string(m.height);
  const std::string size = name + ".size " + std::to_string(m.size);
  // the data must be in the message
  if (m.size < 0) return size + " is negative";
  if (m.size > remaining) {
    return size + " needs " + std::to_string(m.size) + " bytes, " + std::to_string(remaining) +
           " remain";
  }
  // the declared pixels bound what a consumer allocates for it
  if (m.width < 0 || m.height < 0) return name + " image " + dims + " has a negative side";
  const int64_t pixels = int64_t{m.width} * int64_t{m.height};
  if (pixels > limits.max_image_pixels) {
    return name + " image " + dims + " exceeds max_image_pixels (" +
           std::to_string(limits.max_image_pixels) + ")";
  }
  if (m.pixel_format < image::PIXEL_INVALID || m.pixel_format > image::PIXEL_INSTANCE16) {
    return name + ".pixel_format " + std::to_string(m.pixel_format) +
           " is not a known pixel format";
  }
  if (m.encoding < image::ENCODING_INVALID || m.encoding > image::ENCODING_JPEG) {
    return name + ".encoding " + std::to_string(m.encoding) + " is not a known encoding";
  }
  // an image without data stands for no image (a consumer that needs it says so)
  if (m.size == 0) return "";
  if (pixels == 0) {
    return name + " image " + dims + " has no pixels but " + std::to_string(m.size) +
           " bytes of data";
  }
  if (m.pixel_format == image::PIXEL_INVALID) return name + ".pixel_format is PIXEL_INVALID";
  if (m.encoding == image::ENCODING_INVALID) return name + ".encoding is ENCODING_INVALID";
  // the data size against the pixels: exact for RAW, a generous bound for PNG and JPEG
  const int bytes_per_pixel = BytesPerPixel(m.pixel_format);
  const std::string kind =
      std::string(EncodingName(m.encoding)) + " " + PixelFormatName(m.pixel_format) + " image";
  const uint64_t raw = static_cast<uint64_t>(pixels) * static_cast<uint64_t>(bytes_per_pixel);
  const std::string raw_text = "width*height*" + std::to_string(bytes_per_pixel);
  if (m.encoding == image::ENCODING_RAW) {
    if (static_cast<uint64_t>(m.size) != raw) {
      return size + " != " + raw_text + " (" + std::to_string(raw) + ") for a " + kind;
    }
    return "";
  }
  if (m.encoding == image::ENCODING_JPEG && bytes_per_pixel != 1 && bytes_per_pixel != 3) {
    return name + ": JPEG cannot hold a " + PixelFormatName(m.pixel_format) + " image";
  }
  const uint64_t bound = raw > (uint64_t{1} << 40) ? UINT64_MAX : raw * 2 + 4096;
  if (static_cast<uint64_t>(m.size) > bound) {
    return size + " exceeds " + raw_text + "*2+4096 (" + std::to_string(bound) + ") for a " + kind;
  }
  return "";
}

// the fields of image `name`, as image::_decodeNoHash reads them, checked before its data.
bool ReadImage(Reader& reader, const std::string& name, image* m) {
  Reader::Scope scope(reader, name + ".");
  if (!(reader.Primitives("width", __int32_t_decode_array, &m->width, 1) &&
        reader.Primitives("height", __int32_t_decode_array, &m->height, 1) &&
        reader.Primitives("pixel_format", __int8_t_decode_array, &m->pixel_format, 1) &&
        reader.Primitives("encoding", __int8_t_decode_array, &m->encoding, 1) &&
        reader.Primitives("size", __int32_t_decode_array, &m->size, 1))) {
    return false;
  }
  std::string problem = ImageProblem(name, *m, reader.remaining(), reader.limits());
  if (!problem.empty()) return reader.Fail(std::move(problem));
  return reader.Bytes("data", m->size, &m->data);
}

// the encoded size of the smallest instance (empty strings).
int64_t MinInstanceBytes() { return internal::StringLayoutOf<instance>().min_size; }

// num_instances and the instances, checked against the bytes that remain and max_instances
// before the vector is sized.
bool ReadInstances(Reader& reader, int32_t* num_instances, std::vector<instance>* instances) {
  if (!reader.Primitives("num_instances", __int32_t_decode_array, num_instances, 1) ||
      !reader.Count("num_instances", *num_instances, MinInstanceBytes(),
                    reader.limits().max_instances, "max_instances")) {
    return false;
  }
  instances->resize(static_cast<size_t>(*num_instances));
  for (int32_t k = 0; k < *num_instances; ++k) {
    const std::string name = "instances[" + std::to_string(k) + "]";
    if (!reader.Struct(name.c_str(), &(*instances)[static_cast<size_t>(k)])) return false;
  }
  return true;
}

// a grasp array: its count (`count_field`), checked against the bytes that remain and
// max_grasps, then each element (`field`[k]), a struct without variable-length arrays
template <typename Grasp>
bool ReadGrasps(Reader& reader, const char* count_field, const char* field, int32_t* count,
                std::vector<Grasp>* grasps) {
  if (!reader.Primitives(count_field, __int32_t_decode_array, count, 1) ||
      !reader.Count(count_field, *count, internal::StringLayoutOf<Grasp>().min_size,
                    reader.limits().max_grasps, "max_grasps")) {
    return false;
  }
  grasps->resize(static_cast<size_t>(*count));
  for (int32_t k = 0; k < *count; ++k) {
    const std::string name = std::string(field) + "[" + std::to_string(k) + "]";
    if (!reader.Struct(name.c_str(), &(*grasps)[static_cast<size_t>(k)])) return false;
  }
  return true;
}

// both kinds of grasps of a scene or labels message, in their order
template <typename Message>
bool ReadAllGrasps(Reader& reader, Message* m) {
  return ReadGrasps(reader, "num_suction_grasps", "suction_grasps", &m->num_suction_grasps,
                    &m->suction_grasps) &&
         ReadGrasps(reader, "num_jaw_grasps", "jaw_grasps", &m->num_jaw_grasps, &m->jaw_grasps);
}

// the walks of each message type, in the order of its generated _decodeNoHash.
bool ReadScene(Reader& reader, scene* m) {
  return reader.Struct("header", &m->header) && reader.Struct("camera", &m->camera) &&
         ReadInstances(reader, &m->num_instances, &m->instances) &&
         ReadAllGrasps(reader, m) && ReadImage(reader, "color", &m->color) &&
         ReadImage(reader, "depth", &m->depth) &&
         ReadImage(reader, "instance_map", &m->instance_map) &&
         ReadImage(reader, "depth_sensor", &m->depth_sensor);
}

bool ReadLabels(Reader& reader, labels* m) {
  return reader.Struct("header", &m->header) && reader.Struct("camera", &m->camera) &&
         ReadInstances(reader, &m->num_instances, &m->instances) && ReadAllGrasps(reader, m);
}

bool ReadImageMessage(Reader& reader, image* m) { return ReadImage(reader, "image", m); }

bool ReadResendRequest(Reader& reader, resend_request* m) {
  if (!(reader.Struct("header", &m->header) && reader.String("consumer", &m->consumer) &&
        reader.Primitives("num_seqs", __int32_t_decode_array, &m->num_seqs, 1) &&
        reader.Count("num_seqs", m->num_seqs, 8, INT32_MAX, "INT32_MAX"))) {
    return false;
  }
  if (m->num_seqs == 0) return true;
  m->seqs.resize(static_cast<size_t>(m->num_seqs));
  return reader.Primitives("seqs", __int64_t_decode_array, m->seqs.data(), m->num_seqs);
}

// `count` rows of `columns` values each (an lcm-gen `T field[count][columns]`), after the count
// is checked against the bytes that remain and `max`.
template <typename T>
bool ReadRows(Reader& reader, const char* field, int32_t count, int columns, int64_t max,
              const char* limit_name, int (*decode)(const void*, int, int, T*, int),
              std::vector<std::vector<T>>* rows) {
  const std::string count_name = std::string(field) + " rows";
  if (!reader.Count(count_name.c_str(), count, static_cast<int64_t>(sizeof(T)) * columns, max,
                    limit_name)) {
    return false;
  }
  rows->assign(static_cast<size_t>(count), std::vector<T>(static_cast<size_t>(columns)));
  for (std::vector<T>& row : *rows) {
    if (!reader.Primitives(field, decode, row.data(), columns)) return false;
  }
  return true;
}

bool ReadModel(Reader& reader, model* m) {
  const int64_t max_vertices = reader.limits().max_model_vertices;
  return reader.Struct("header", &m->header) &&
         reader.Primitives("class_id", __int32_t_decode_array, &m->class_id, 1) &&
         reader.String("class_name", &m->class_name) && reader.String("mesh", &m->mesh) &&
         reader.Primitives("num_vertices", __int32_t_decode_array, &m->num_vertices, 1) &&
         ReadRows(reader, "vertices_mm", m->num_vertices, 3, max_vertices, "max_model_vertices",
                  __float_decode_array, &m->vertices_mm) &&
         ReadRows(reader, "normals", m->num_vertices, 3, max_vertices, "max_model_vertices",
                  __float_decode_array, &m->normals) &&
         reader.Primitives("num_triangles", __int32_t_decode_array, &m->num_triangles, 1) &&
         ReadRows(reader, "triangles", m->num_triangles, 3, 2 * max_vertices,
                  "2 * max_model_vertices", __int32_t_decode_array, &m->triangles) &&
         reader.Primitives("diameter_mm", __double_decode_array, &m->diameter_mm, 1) &&
         reader.Primitives("num_discrete_symmetries", __int32_t_decode_array,
                           &m->num_discrete_symmetries, 1) &&
         ReadRows(reader, "discrete_symmetries", m->num_discrete_symmetries, 16, 1000, "1000",
                  __double_decode_array, &m->discrete_symmetries) &&
         reader.Primitives("num_continuous_symmetries", __int32_t_decode_array,
                           &m->num_continuous_symmetries, 1) &&
         ReadRows(reader, "continuous_axes", m->num_continuous_symmetries, 3, 3, "3",
                  __double_decode_array, &m->continuous_axes) &&
         ReadRows(reader, "continuous_offsets_mm", m->num_continuous_symmetries, 3, 3, "3",
                  __double_decode_array, &m->continuous_offsets_mm);
}

// the checked walk `read` of a whole message: envelope, fields, nothing left over.
template <typename Message>
bool DecodeWalked(const uint8_t* data, size_t size, const DecodeLimits& limits, Message* out,
                  std::string* why, bool (*read)(Reader&, Message*)) {
  if (!internal::CheckEnvelope(data, size, limits, Message::getHash(), Message::getTypeName(),
                               why)) {
    return false;
  }
  try {
    Reader reader(data, size, limits);
    Message message{};
    if (!read(reader, &message)) return internal::Refuse(reader.reason(), why);
    if (!internal::CheckSpan(reader.position() - static_cast<int>(kFingerprintBytes), size,
                             Message::getTypeName(), why)) {
      return false;
    }
    *out = std::move(message);
    return true;
  } catch (const std::exception& error) {
    // only an allocation within the limits that the system could not satisfy gets here
    return internal::Refuse(
        std::string("cannot decode stackgen.") + Message::getTypeName() + ": " + error.what(), why);
  }
}

// big-endian unsigned integers of an image file header.
uint32_t Big32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | p[3];
}
uint32_t Big16(const uint8_t* p) { return (uint32_t{p[0]} << 8) | p[1]; }

// "file says AxB, the image declares CxD" when the sizes differ, else "".
std::string DimsMismatch(const char* format, uint32_t width, uint32_t height, const image& m) {
  if (width == static_cast<uint32_t>(m.width) && height == static_cast<uint32_t>(m.height)) {
    return "";
  }
  return std::string(format) + " header says " + std::to_string(width) + "x" +
         std::to_string(height) + ", the image declares " + std::to_string(m.width) + "x" +
         std::to_string(m.height);
}

// what is wrong with the PNG in `m` (IHDR against the declared size and pixel format).
std::string PngProblem(const image& m) {
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  const uint8_t* p = m.data.data();
  // signature, then the IHDR chunk: length 13, "IHDR", width, height, depth, colour type, ...
  if (m.data.size() < 8 + 8 + 13 || std::memcmp(p, kSignature, 8) != 0) {
    return "data is not a PNG file";
  }
  if (Big32(p + 8) != 13 || std::memcmp(p + 12, "IHDR", 4) != 0) {
    return "PNG does not start with an IHDR chunk";
  }
  std::string problem = DimsMismatch("PNG", Big32(p + 16), Big32(p + 20), m);
  if (!problem.empty()) return problem;
  // what OpenCV writes for each pixel format: 8-bit RGB (2), 8-bit gray (0), 16-bit gray (0)
  const int bytes_per_pixel = BytesPerPixel(m.pixel_format);
  if (bytes_per_pixel == 0) return "pixel_format is not a known pixel format";
  const int bit_depth = p[24];
  const int colour_type = p[25];
  const int want_depth = bytes_per_pixel == 2 ? 16 : 8;
  const int want_colour = m.pixel_format == image::PIXEL_RGB8 ? 2 : 0;
  if (bit_depth != want_depth || colour_type != want_colour) {
    return "PNG has bit depth " + std::to_string(bit_depth) + " and colour type " +
           std::to_string(colour_type) + ", a " + PixelFormatName(m.pixel_format) +
           " image needs " + std::to_string(want_depth) + " and " + std::to_string(want_colour);
  }
  return "";
}

// what is wrong with the JPEG in `m` (the first SOFn marker against the declared size).
std::string JpegProblem(const image& m) {
  const uint8_t* p = m.data.data();
  const size_t size = m.data.size();
  if (size < 4 || p[0] != 0xFF || p[1] != 0xD8 || p[2] != 0xFF) return "data is not a JPEG file";
  const int want_components =
      m.pixel_format == image::PIXEL_RGB8 ? 3 : (m.pixel_format == image::PIXEL_GRAY8 ? 1 : 0);
  if (want_components == 0) {
    return std::string("JPEG cannot hold a ") + PixelFormatName(m.pixel_format) + " image";
  }
  // walk the marker segments after SOI up to the first frame header (SOF0..SOF15 but DHT C4,
  // JPG C8 and DAC CC); a scan or the end before it means there is no frame
  size_t pos = 2;
  while (pos < size) {
    if (p[pos] != 0xFF) return "JPEG has no marker at offset " + std::to_string(pos);
    while (pos < size && p[pos] == 0xFF) ++pos;
    if (pos >= size) break;
    const uint8_t marker = p[pos++];
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) continue;
    if (marker == 0xD8 || marker == 0xD9 || marker == 0xDA || marker == 0x00) {
      return "JPEG has no frame header (SOFn) before marker " + std::to_string(marker);
    }
    if (pos + 2 > size) break;
    const size_t length = Big16(p + pos);
    if (length < 2 || pos + length > size) return "JPEG marker segment runs past the data";
    const bool frame =
        marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
    if (frame) {
      if (length < 8) return "JPEG frame header is too short";
      const int precision = p[pos + 2];
      const int components = p[pos + 7];
      std::string problem = DimsMismatch("JPEG", Big16(p + pos + 5), Big16(p + pos + 3), m);
      if (!problem.empty()) return problem;
      if (precision != 8 || components != want_components) {
        return "JPEG has " + std::to_string(components) + " components of " +
               std::to_string(precision) + " bits, a " + PixelFormatName(m.pixel_format) +
               " image needs " + std::to_string(want_components) + " of 8";
      }
      return "";
    }
    pos += length;
  }
  return "JPEG ends before a frame header (SOFn)";
}

}  // namespace

template <>
bool DecodeBounded<scene>(const uint8_t* data, size_t size, const DecodeLimits& limits, scene* out,
                          std::string* why) {
  return DecodeWalked(data, size, limits, out, why, &ReadScene);
}

template <>
bool DecodeBounded<labels>(const uint8_t* data, size_t size, const DecodeLimits& limits,
                           labels* out, std::string* why) {
  return DecodeWalked(data, size, limits, out, why, &ReadLabels);
}

template <>
bool DecodeBounded<image>(const uint8_t* data, size_t size, const DecodeLimits& limits, image* out,
                          std::string* why) {
  return DecodeWalked(data, size, limits, out, why, &ReadImageMessage);
}

template <>
bool DecodeBounded<resend_request>(const uint8_t* data, size_t size, const DecodeLimits& limits,
                                   resend_request* out, std::string* why) {
  return DecodeWalked(data, size, limits, out, why, &ReadResendRequest);
}

template <>
bool DecodeBounded<model>(const uint8_t* data, size_t size, const DecodeLimits& limits, model* out,
                          std::string* why) {
  return DecodeWalked(data, size, limits, out, why, &ReadModel);
}

bool CheckEncodedImageDims(const image& m, std::string* why) {
  const std::string name = "image " + std::to_string(m.width) + "x" + std::to_string(m.height);
  // the data the fields describe
  if (m.size < 0 || m.data.size() != static_cast<size_t>(m.size)) {
    return internal::Refuse(name + ": data holds " + std::to_string(m.data.size()) +
                                " bytes, size says " + std::to_string(m.size),
                            why);
  }
  if (m.size == 0) return true;
  if (m.width <= 0 || m.height <= 0) return internal::Refuse(name + " has no pixels", why);
  std::string problem;
  switch (m.encoding) {
    case image::ENCODING_RAW: {
      const int bytes_per_pixel = BytesPerPixel(m.pixel_format);
      const uint64_t raw = static_cast<uint64_t>(m.width) * static_cast<uint64_t>(m.height) *
                           static_cast<uint64_t>(bytes_per_pixel);
      if (bytes_per_pixel == 0) {
        problem = "pixel_format " + std::to_string(m.pixel_format) + " is not a known format";
      } else if (static_cast<uint64_t>(m.size) != raw) {
        problem = "size " + std::to_string(m.size) + " != width*height*" +
                  std::to_string(bytes_per_pixel) + " (" + std::to_string(raw) + ")";
      }
      break;
    }
    case image::ENCODING_PNG:
      problem = PngProblem(m);
      break;
    case image::ENCODING_JPEG:
      problem = JpegProblem(m);
      break;
    default:
      problem = "encoding " + std::to_string(m.encoding) + " is not RAW, PNG or JPEG";
  }
  if (!problem.empty()) return internal::Refuse(name + ": " + problem, why);
  return true;
}

}  // namespace stackgen
