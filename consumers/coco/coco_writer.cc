#include "consumers/coco/coco_writer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <limits>
#include <set>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// id layout: image id = generator_id * 1e9 + seq + 1, annotation id = image id * 1000 +
// instance_id; these bounds keep both unique and inside int64
constexpr int64_t kSeqsPerGenerator = 1000000000;
constexpr int64_t kMaxSeq = kSeqsPerGenerator - 2;
constexpr int32_t kMaxGeneratorId = 9000000;
constexpr int32_t kMaxInstanceId = 999;

constexpr const char* kAnnotationsFile = "annotations.json";
constexpr const char* kJournalFile = "annotations.journal";
constexpr const char* kImagesFolder = "images";

// the scene's name in error messages: "scene <generator_id>/<seq>"
std::string SceneName(const stackgen::scene& scene) {
  return "scene " + std::to_string(scene.header.generator_id) + "/" +
         std::to_string(scene.header.seq);
}

// the runs of a COCO compressed RLE string (cocoapi maskApi.c rleFrString); throws
// std::runtime_error on a malformed string. Consumers do not link gen/, hence this small copy.
std::vector<uint32_t> ParseRleCounts(const std::string& counts) {
  std::vector<uint32_t> runs;
  size_t p = 0;
  while (p < counts.size()) {
    int64_t x = 0;
    int k = 0;
    bool more = true;
    while (more) {
      if (p >= counts.size() || k >= 7) throw std::runtime_error("a number is cut short");
      const int c = static_cast<unsigned char>(counts[p]) - 48;
      if (c < 0 || c > 63) throw std::runtime_error("char outside '0'..'o'");
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

[[noreturn]] void Fail(const std::string& scene_name, const std::string& text) {
  throw InvalidSceneError(scene_name + ": " + text);
}

void CheckFinite(double value, const std::string& scene_name, const std::string& field) {
  if (!std::isfinite(value)) {
    throw InvalidSceneError(scene_name + ": " + field + " is not finite");
  }
}

void CheckPose(const stackgen::pose& pose, const std::string& scene_name,
               const std::string& field) {
  for (int i = 0; i < 3; ++i) {
    CheckFinite(pose.translation_mm[i], scene_name,
                field + ".translation_mm[" + std::to_string(i) + "]");
  }
  for (int i = 0; i < 9; ++i) {
    CheckFinite(pose.rotation[i], scene_name, field + ".rotation[" + std::to_string(i) + "]");
  }
  for (int i = 0; i < 4; ++i) {
    CheckFinite(pose.quaternion_wxyz[i], scene_name,
                field + ".quaternion_wxyz[" + std::to_string(i) + "]");
  }
}

// `counts` (a COCO compressed RLE string, the field `field`) must cover `image_area` pixels
// and hold `expected` of them (the value of `count_field`)
void CheckMask(const std::string& counts, int32_t expected, uint64_t image_area,
               const std::string& scene_name, const std::string& field,
               const std::string& count_field) {
  if (counts.empty()) Fail(scene_name, field + " is empty");
  std::vector<uint32_t> runs;
  try {
    runs = ParseRleCounts(counts);
  } catch (const std::runtime_error& error) {
    Fail(scene_name, field + " is not a COCO RLE string: " + error.what());
  }
  uint64_t total = 0, area = 0;
  for (size_t k = 0; k < runs.size(); ++k) {
    total += runs[k];
    if (k % 2 == 1) area += runs[k];
  }
  if (total != image_area) {
    Fail(scene_name, field + " covers " + std::to_string(total) + " pixels, the image has " +
                         std::to_string(image_area));
  }
  if (area != static_cast<uint64_t>(expected)) {
    Fail(scene_name, field + " holds " + std::to_string(area) + " pixels, " + count_field + " is " +
                         std::to_string(expected));
  }
}

uint32_t BigEndian32(const uint8_t* bytes) {
  return (uint32_t{bytes[0]} << 24) | (uint32_t{bytes[1]} << 16) | (uint32_t{bytes[2]} << 8) |
         uint32_t{bytes[3]};
}

// width and height from a PNG's IHDR chunk, without decoding; false if it is not a PNG
bool PngSize(const std::vector<uint8_t>& data, int64_t* width, int64_t* height) {
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (data.size() < 24 || !std::equal(kSignature, kSignature + 8, data.begin()) ||
      std::string(data.begin() + 12, data.begin() + 16) != "IHDR") {
    return false;
  }
  *width = BigEndian32(&data[16]);
  *height = BigEndian32(&data[20]);
  return true;
}

// width and height from a JPEG's start-of-frame segment, without decoding; false if none
bool JpegSize(const std::vector<uint8_t>& data, int64_t* width, int64_t* height) {
  if (data.size() < 4 || data[0] != 0xff || data[1] != 0xd8) return false;
  size_t p = 2;
  while (p + 1 < data.size()) {
    // a marker: 0xff (maybe repeated as fill), then its code
    if (data[p] != 0xff) return false;
    while (p < data.size() && data[p] == 0xff) ++p;
    if (p >= data.size()) return false;
    const uint8_t marker = data[p++];
    if (marker == 0x01 || (marker >= 0xd0 && marker <= 0xd8)) continue;  // no length
    if (marker == 0xd9 || marker == 0xda) return false;  // end of image or scan: no frame
    if (p + 2 > data.size()) return false;
    const size_t length = (size_t{data[p]} << 8) | data[p + 1];
    // SOF0..SOF15 except DHT (c4), JPG (c8), DAC (cc): precision, height, width
    if (marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc) {
      if (p + 7 > data.size()) return false;
      *height = (int64_t{data[p + 3]} << 8) | data[p + 4];
      *width = (int64_t{data[p + 5]} << 8) | data[p + 6];
      return true;
    }
    p += length;
  }
  return false;
}

std::string ImageBaseName(const stackgen::scene& scene) {
  char seq[32];
  std::snprintf(seq, sizeof(seq), "%06lld", static_cast<long long>(scene.header.seq));
  return std::to_string(scene.header.generator_id) + "_" + seq;
}

// writes `size` bytes to `path` through `path`.tmp and a rename
void WriteFileAtomically(const fs::path& path, const char* bytes, size_t size) {
  const fs::path temporary = path.string() + ".tmp";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(bytes, static_cast<std::streamsize>(size));
    out.close();
    if (!out) throw std::runtime_error("cannot write " + temporary.string());
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error) {
    throw std::runtime_error("cannot rename " + temporary.string() + " to " + path.string() + ": " +
                             error.message());
  }
}

json PoseJson(const stackgen::pose& pose) {
  return {{"translation_mm", std::vector<double>(pose.translation_mm, pose.translation_mm + 3)},
          {"rotation", std::vector<double>(pose.rotation, pose.rotation + 9)},
          {"quaternion_wxyz", std::vector<double>(pose.quaternion_wxyz, pose.quaternion_wxyz + 4)}};
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

// copies `length` bytes at `offset` of `in` to `out`
void CopyRange(std::ifstream& in, std::ofstream& out, uint64_t offset, uint64_t length,
               const std::string& in_name) {
  in.seekg(static_cast<std::streamoff>(offset));
  char buffer[1 << 16];
  while (length > 0) {
    const std::streamsize chunk =
        static_cast<std::streamsize>(std::min<uint64_t>(length, sizeof(buffer)));
    in.read(buffer, chunk);
    if (in.gcount() != chunk) {
      throw std::runtime_error("cannot read " + in_name + " at offset " + std::to_string(offset));
    }
    out.write(buffer, chunk);
    length -= static_cast<uint64_t>(chunk);
  }
}

}  // namespace

CocoWriter::CocoWriter(const std::string& dir, const CocoWriterOptions& options)
    : dir_(dir), options_(options) {
  if (options_.min_visib_fract &&
      !(*options_.min_visib_fract >= 0.0 && *options_.min_visib_fract <= 1.0)) {
    throw std::runtime_error("min_visib_fract " + std::to_string(*options_.min_visib_fract) +
                             " outside [0, 1]");
  }
  // never overwrite a dataset
  const fs::path annotations = fs::path(dir_) / kAnnotationsFile;
  std::error_code error;
  if (fs::exists(annotations, error) && fs::file_size(annotations, error) > 0) {
    throw std::runtime_error(annotations.string() +
                             " already exists; will not overwrite it (choose another output "
                             "folder or remove it)");
  }
  // the folders and a fresh journal
  fs::create_directories(fs::path(dir_) / kImagesFolder, error);
  if (error) {
    throw std::runtime_error("cannot create " + (fs::path(dir_) / kImagesFolder).string() + ": " +
                             error.message());
  }
  journal_path_ = (fs::path(dir_) / kJournalFile).string();
  journal_.open(journal_path_, std::ios::binary | std::ios::trunc);
  if (!journal_) throw std::runtime_error("cannot create " + journal_path_);
}

CocoWriter::~CocoWriter() {
  journal_.close();
  // the journal is only worth keeping for scenes that never reached annotations.json
  if (finished_ || index_.empty()) {
    std::error_code ignored;
    fs::remove(journal_path_, ignored);
  }
}

int64_t CocoWriter::ImageId(int32_t generator_id, int64_t seq) {
  return int64_t{generator_id} * kSeqsPerGenerator + seq + 1;
}

int64_t CocoWriter::AnnotationId(int64_t image_id, int32_t instance_id) {
  return image_id * 1000 + instance_id;
}

void CocoWriter::Validate(const stackgen::scene& scene) const {
  const std::string name = SceneName(scene);

  // header: ids must fit the id layout
  if (scene.header.generator_id < 0 || scene.header.generator_id > kMaxGeneratorId) {
    Fail(name, "header.generator_id " + std::to_string(scene.header.generator_id) + " outside 0.." +
                   std::to_string(kMaxGeneratorId));
  }
  if (scene.header.seq < 0 || scene.header.seq > kMaxSeq) {
    Fail(name, "header.seq " + std::to_string(scene.header.seq) + " outside 0.." +
                   std::to_string(kMaxSeq));
  }

  // camera
  const stackgen::camera_info& camera = scene.camera;
  if (camera.width <= 0 || camera.height <= 0) {
    Fail(name, "camera.width x camera.height " + std::to_string(camera.width) + " x " +
                   std::to_string(camera.height) + " is not a positive size");
  }
  CheckFinite(camera.fx, name, "camera.fx");
  CheckFinite(camera.fy, name, "camera.fy");
  CheckFinite(camera.cx, name, "camera.cx");
  CheckFinite(camera.cy, name, "camera.cy");
  CheckFinite(camera.depth_scale_mm, name, "camera.depth_scale_mm");
  CheckPose(camera.world_from_camera, name, "camera.world_from_camera");

  // colour image: size, format, encoding, bytes
  const stackgen::image& color = scene.color;
  if (color.width != camera.width || color.height != camera.height) {
    Fail(name, "color.width x color.height " + std::to_string(color.width) + " x " +
                   std::to_string(color.height) + " differs from camera " +
                   std::to_string(camera.width) + " x " + std::to_string(camera.height));
  }
  int channels = 0;
  if (color.pixel_format == stackgen::image::PIXEL_RGB8) {
    channels = 3;
  } else if (color.pixel_format == stackgen::image::PIXEL_GRAY8) {
    channels = 1;
  } else {
    Fail(name,
         "color.pixel_format " + std::to_string(color.pixel_format) + " is not RGB8 or GRAY8");
  }
  if (color.size < 0 || static_cast<size_t>(color.size) != color.data.size()) {
    Fail(name, "color.size " + std::to_string(color.size) + " differs from the " +
                   std::to_string(color.data.size()) + " bytes of color.data");
  }
  int64_t encoded_width = 0, encoded_height = 0;
  switch (color.encoding) {
    case stackgen::image::ENCODING_RAW: {
      const int64_t expected = int64_t{color.width} * color.height * channels;
      if (color.size != expected) {
        Fail(name, "color.size " + std::to_string(color.size) + " is not width * height * " +
                       std::to_string(channels) + " = " + std::to_string(expected) + " for RAW");
      }
      break;
    }
    case stackgen::image::ENCODING_PNG:
      if (!PngSize(color.data, &encoded_width, &encoded_height)) {
        Fail(name, "color.data is not a PNG file (encoding PNG)");
      }
      break;
    case stackgen::image::ENCODING_JPEG:
      if (!JpegSize(color.data, &encoded_width, &encoded_height)) {
        Fail(name, "color.data is not a JPEG file with a frame header (encoding JPEG)");
      }
      break;
    default:
      Fail(name, "color.encoding " + std::to_string(color.encoding) + " is not RAW, PNG or JPEG");
  }
  if (color.encoding != stackgen::image::ENCODING_RAW &&
      (encoded_width != color.width || encoded_height != color.height)) {
    Fail(name, "color.data holds a " + std::to_string(encoded_width) + " x " +
                   std::to_string(encoded_height) + " image, color.width x color.height is " +
                   std::to_string(color.width) + " x " + std::to_string(color.height));
  }

  // instances
  if (scene.num_instances < 0 ||
      static_cast<size_t>(scene.num_instances) != scene.instances.size()) {
    Fail(name, "num_instances " + std::to_string(scene.num_instances) + " differs from the " +
                   std::to_string(scene.instances.size()) + " entries of instances");
  }
  const uint64_t image_area = static_cast<uint64_t>(camera.width) * camera.height;
  std::set<int32_t> instance_ids;
  std::map<int32_t, std::string> scene_categories;
  for (size_t i = 0; i < scene.instances.size(); ++i) {
    const stackgen::instance& instance = scene.instances[i];
    const std::string field = "instances[" + std::to_string(i) + "]";
    // ids and class
    if (instance.instance_id < 1 || instance.instance_id > kMaxInstanceId) {
      Fail(name, field + ".instance_id " + std::to_string(instance.instance_id) + " outside 1.." +
                     std::to_string(kMaxInstanceId) +
                     " (annotation id = image id * 1000 + instance_id)");
    }
    if (!instance_ids.insert(instance.instance_id).second) {
      Fail(name, field + ".instance_id " + std::to_string(instance.instance_id) + " repeated");
    }
    if (instance.class_id < 1) {
      Fail(name, field + ".class_id " + std::to_string(instance.class_id) + " is not >= 1");
    }
    if (instance.class_name.empty()) Fail(name, field + ".class_name is empty");
    const auto known = categories_.find(instance.class_id);
    const auto in_scene = scene_categories.emplace(instance.class_id, instance.class_name).first;
    if ((known != categories_.end() && known->second != instance.class_name) ||
        in_scene->second != instance.class_name) {
      Fail(name, field + ".class_name \"" + instance.class_name + "\" differs from \"" +
                     (known != categories_.end() ? known->second : in_scene->second) +
                     "\" seen before for class_id " + std::to_string(instance.class_id));
    }
    // numbers
    CheckPose(instance.camera_from_object, name, field + ".camera_from_object");
    CheckPose(instance.world_from_object, name, field + ".world_from_object");
    for (int k = 0; k < 3; ++k) {
      CheckFinite(instance.posture_deg[k], name, field + ".posture_deg[" + std::to_string(k) + "]");
    }
    if (!(instance.visib_fract >= 0.0 && instance.visib_fract <= 1.0)) {
      Fail(name,
           field + ".visib_fract " + std::to_string(instance.visib_fract) + " outside [0, 1]");
    }
    if (instance.px_count_all < 0 || instance.px_count_visib < 0) {
      Fail(name, field + ".px_count_all / px_count_visib is negative");
    }
    if (instance.px_count_visib > instance.px_count_all) {
      Fail(name, field + ".px_count_visib " + std::to_string(instance.px_count_visib) +
                     " exceeds px_count_all " + std::to_string(instance.px_count_all));
    }
    // boxes inside the image
    for (const auto& [box, box_name] : {std::make_pair(instance.bbox_obj, ".bbox_obj"),
                                        std::make_pair(instance.bbox_visib, ".bbox_visib")}) {
      if (box[0] < 0 || box[1] < 0 || box[2] < 0 || box[3] < 0 || box[0] + box[2] > camera.width ||
          box[1] + box[3] > camera.height) {
        Fail(name, field + box_name + " [" + std::to_string(box[0]) + ", " +
                       std::to_string(box[1]) + ", " + std::to_string(box[2]) + ", " +
                       std::to_string(box[3]) + "] is not inside the " +
                       std::to_string(camera.width) + " x " + std::to_string(camera.height) +
                       " image");
      }
    }
    // the visible and the full mask must cover the image and hold their pixel counts
    CheckMask(instance.mask_visib_rle, instance.px_count_visib, image_area, name,
              field + ".mask_visib_rle", "px_count_visib");
    CheckMask(instance.mask_obj_rle, instance.px_count_all, image_area, name,
              field + ".mask_obj_rle", "px_count_all");
    // the generator's label: annotated, ignored or neither; both need visible pixels
    if (instance.annotated && instance.ignored) {
      Fail(name, field + ".ignored and " + field + ".annotated are both true");
    }
    if ((instance.annotated || instance.ignored) && instance.px_count_visib == 0) {
      Fail(name, field + (instance.annotated ? ".annotated" : ".ignored") +
                     " is true but px_count_visib is 0");
    }
  }
}

std::string CocoWriter::WriteImageFile(const stackgen::scene& scene) const {
  const stackgen::image& color = scene.color;
  const std::string base = ImageBaseName(scene);
  const bool jpeg = color.encoding == stackgen::image::ENCODING_JPEG;
  const std::string file_name = base + (jpeg ? ".jpg" : ".png");
  const fs::path path = fs::path(dir_) / kImagesFolder / file_name;

  if (color.encoding != stackgen::image::ENCODING_RAW) {
    // PNG and JPEG: the bytes as they came
    WriteFileAtomically(path, reinterpret_cast<const char*>(color.data.data()), color.data.size());
    return file_name;
  }
  // RAW: encode to PNG (OpenCV wants BGR order)
  const bool rgb = color.pixel_format == stackgen::image::PIXEL_RGB8;
  const cv::Mat pixels(color.height, color.width, rgb ? CV_8UC3 : CV_8UC1,
                       const_cast<uint8_t*>(color.data.data()));
  cv::Mat to_encode = pixels;
  if (rgb) cv::cvtColor(pixels, to_encode, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> png;
  if (!cv::imencode(".png", to_encode, png)) {
    throw std::runtime_error("cannot encode " + path.string() + " as PNG");
  }
  WriteFileAtomically(path, reinterpret_cast<const char*>(png.data()), png.size());
  return file_name;
}

uint64_t CocoWriter::AppendToJournal(const std::string& text) {
  const uint64_t offset = journal_size_;
  journal_.write(text.data(), static_cast<std::streamsize>(text.size()));
  journal_.put('\n');
  if (!journal_) throw std::runtime_error("cannot write " + journal_path_);
  journal_size_ += text.size() + 1;
  return offset;
}

bool CocoWriter::Add(const stackgen::scene& scene) {
  // store each (generator_id, seq) once
  const int64_t image_id = ImageId(scene.header.generator_id, scene.header.seq);
  if (index_.count(image_id) != 0) return false;
  Validate(scene);

  // the image record
  const stackgen::camera_info& camera = scene.camera;
  const std::string file_name = WriteImageFile(scene);
  json camera_json = {{"fx", camera.fx},
                      {"fy", camera.fy},
                      {"cx", camera.cx},
                      {"cy", camera.cy},
                      {"world_from_camera", PoseJson(camera.world_from_camera)},
                      {"depth_scale_mm", camera.depth_scale_mm}};
  const json image = {{"id", image_id},
                      {"file_name", file_name},
                      {"width", camera.width},
                      {"height", camera.height},
                      {"stackgen",
                       {{"seq", scene.header.seq},
                        {"generator_id", scene.header.generator_id},
                        {"seed", scene.header.seed},
                        {"camera", std::move(camera_json)}}}};

  // the annotation records, by instance id (= by annotation id)
  std::vector<const stackgen::instance*> instances;
  for (const stackgen::instance& instance : scene.instances) instances.push_back(&instance);
  std::sort(instances.begin(), instances.end(),
            [](const stackgen::instance* a, const stackgen::instance* b) {
              return a->instance_id < b->instance_id;
            });
  std::string annotations;
  int64_t scene_annotations = 0, scene_crowd = 0, scene_dropped = 0;
  for (const stackgen::instance* instance : instances) {
    // the generator's label decides: annotated -> iscrowd 0, ignored -> iscrowd 1, else nothing;
    // a min_visib_fract of our own only drops more
    const bool below_own_threshold =
        options_.min_visib_fract && instance->visib_fract < *options_.min_visib_fract;
    const bool crowd = instance->ignored;
    const bool annotation_kept = instance->annotated && !below_own_threshold;
    if (!annotation_kept && !crowd) {
      ++scene_dropped;
      continue;
    }
    const stackgen::pose& camera_from_object = instance->camera_from_object;
    const stackgen::pose& world_from_object = instance->world_from_object;
    const json annotation = {
        {"id", AnnotationId(image_id, instance->instance_id)},
        {"image_id", image_id},
        {"category_id", instance->class_id},
        {"segmentation",
         {{"size", {camera.height, camera.width}}, {"counts", instance->mask_visib_rle}}},
        {"area", instance->px_count_visib},
        {"bbox", std::vector<int32_t>(instance->bbox_visib, instance->bbox_visib + 4)},
        {"iscrowd", crowd ? 1 : 0},
        {"amodal_segmentation",
         {{"size", {camera.height, camera.width}}, {"counts", instance->mask_obj_rle}}},
        {"amodal_bbox", std::vector<int32_t>(instance->bbox_obj, instance->bbox_obj + 4)},
        {"instance_id", instance->instance_id},
        {"visib_fract", instance->visib_fract},
        {"px_count_all", instance->px_count_all},
        {"px_count_visib", instance->px_count_visib},
        {"bbox_obj", std::vector<int32_t>(instance->bbox_obj, instance->bbox_obj + 4)},
        {"posture_deg", std::vector<double>(instance->posture_deg, instance->posture_deg + 3)},
        {"resting_face", instance->resting_face},
        {"cam_R_m2c",
         std::vector<double>(camera_from_object.rotation, camera_from_object.rotation + 9)},
        {"cam_t_m2c", std::vector<double>(camera_from_object.translation_mm,
                                          camera_from_object.translation_mm + 3)},
        {"world_R_m2w",
         std::vector<double>(world_from_object.rotation, world_from_object.rotation + 9)},
        {"world_t_m2w", std::vector<double>(world_from_object.translation_mm,
                                            world_from_object.translation_mm + 3)}};
    if (!annotations.empty()) annotations += ",\n";
    annotations += annotation.dump();
    if (crowd) {
      ++scene_crowd;
    } else {
      ++scene_annotations;
    }
  }

  // journal both, then index them
  JournalEntry entry;
  entry.generator_id = scene.header.generator_id;
  entry.seq = scene.header.seq;
  const std::string image_text = image.dump();
  entry.image_offset = AppendToJournal(image_text);
  entry.image_length = image_text.size();
  if (!annotations.empty()) {
    entry.annotations_offset = AppendToJournal(annotations);
    entry.annotations_length = annotations.size();
  }
  index_.emplace(image_id, entry);
  for (const stackgen::instance& instance : scene.instances) {
    categories_.emplace(instance.class_id, instance.class_name);
  }
  num_annotations_ += scene_annotations;
  num_crowd_ += scene_crowd;
  num_dropped_ += scene_dropped;
  finished_ = false;
  return true;
}

void CocoWriter::Finish() {
  journal_.flush();
  if (!journal_) throw std::runtime_error("cannot write " + journal_path_);
  std::ifstream journal(journal_path_, std::ios::binary);
  if (!journal) throw std::runtime_error("cannot read " + journal_path_);

  const fs::path final_path = fs::path(dir_) / kAnnotationsFile;
  const fs::path temporary = final_path.string() + ".tmp";
  std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
  if (!out) throw std::runtime_error("cannot create " + temporary.string());

  // info and licenses
  const std::string date = UtcNow();
  const json info = {{"description", options_.description},
                     {"version", "1.0"},
                     {"year", std::stoi(date.substr(0, 4))},
                     {"contributor", "stackgen-coco"},
                     {"url", ""},
                     {"date_created", date}};
  out << "{\n\"info\": " << info.dump() << ",\n\"licenses\": [],\n\"images\": [\n";

  // images, by id
  bool first = true;
  for (const auto& [image_id, entry] : index_) {
    if (!first) out << ",\n";
    first = false;
    CopyRange(journal, out, entry.image_offset, entry.image_length, journal_path_);
  }

  // categories, by id
  out << "\n],\n\"categories\": [\n";
  first = true;
  for (const auto& [class_id, class_name] : categories_) {
    if (!first) out << ",\n";
    first = false;
    out << json{{"id", class_id}, {"name", class_name}, {"supercategory", "part"}}.dump();
  }

  // annotations, by id (image ids ascending, instance ids ascending within an image)
  out << "\n],\n\"annotations\": [\n";
  first = true;
  for (const auto& [image_id, entry] : index_) {
    if (entry.annotations_length == 0) continue;
    if (!first) out << ",\n";
    first = false;
    CopyRange(journal, out, entry.annotations_offset, entry.annotations_length, journal_path_);
  }
  out << "\n]\n}\n";
  out.close();
  if (!out) throw std::runtime_error("cannot write " + temporary.string());

  // publish it whole
  std::error_code error;
  fs::rename(temporary, final_path, error);
  if (error) {
    throw std::runtime_error("cannot rename " + temporary.string() + " to " + final_path.string() +
                             ": " + error.message());
  }
  finished_ = true;
}

std::map<int32_t, int64_t> CocoWriter::LostPerGenerator() const {
  // first seq, last seq and count per generator; the index is sorted by generator, then seq
  struct Span {
    int64_t first = 0, last = 0, count = 0;
  };
  std::map<int32_t, Span> spans;
  for (const auto& [image_id, entry] : index_) {
    Span& span = spans[entry.generator_id];
    if (span.count == 0) span.first = entry.seq;
    span.last = entry.seq;
    ++span.count;
  }
  std::map<int32_t, int64_t> lost;
  for (const auto& [generator_id, span] : spans) {
    lost[generator_id] = span.last - span.first + 1 - span.count;
  }
  return lost;
}

int64_t CocoWriter::num_lost() const {
  int64_t total = 0;
  for (const auto& [generator_id, lost] : LostPerGenerator()) total += lost;
  return total;
}

}  // namespace stackgen
