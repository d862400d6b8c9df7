#include "consumers/feed/scene_data.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <set>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/bounded_decode.h"
#include "bus/rle_counts.h"
#include "bus/scene_contract.h"

namespace stackgen::feed {
namespace {

// the most mask pixels one scene may hold (instances x width x height): 4 Gi, a bound
// against a message that would make the full masks fill memory
constexpr int64_t kMaxMaskPixels = int64_t{1} << 32;

bool Refuse(const std::string& reason, std::string* why) {
  if (why != nullptr) *why = reason;
  return false;
}

bool Finite(const double* values, int count) {
  for (int k = 0; k < count; ++k) {
    if (!std::isfinite(values[k])) return false;
  }
  return true;
}

bool FinitePose(const pose& p) {
  return Finite(p.translation_mm, 3) && Finite(p.rotation, 9) && Finite(p.quaternion_wxyz, 4);
}

// a box [x, y, w, h] inside a width x height image
bool BoxInside(const int32_t box[4], int width, int height) {
  return box[0] >= 0 && box[1] >= 0 && box[2] >= 0 && box[3] >= 0 &&
         int64_t{box[0]} + box[2] <= width && int64_t{box[1]} + box[3] <= height;
}

// checks an image of the scene: its format, its size against the camera's, its encoded header
bool CheckImage(const image& m, const std::string& field, int width, int height,
                std::initializer_list<int8_t> formats, std::string* why) {
  bool known = false;
  for (const int8_t format : formats) known = known || m.pixel_format == format;
  if (!known) {
    return Refuse(field + ".pixel_format " + std::to_string(m.pixel_format) +
                      " is not one this image may have",
                  why);
  }
  if (m.width != width || m.height != height) {
    return Refuse(field + " is " + std::to_string(m.width) + "x" + std::to_string(m.height) +
                      ", the camera " + std::to_string(width) + "x" + std::to_string(height),
                  why);
  }
  std::string problem;
  if (!CheckEncodedImageDims(m, &problem)) return Refuse(field + ": " + problem, why);
  return true;
}

}  // namespace

int64_t DecodeRleWindow(const std::string& counts, int height, int width, int x0, int y0,
                        int window_width, int window_height, uint8_t* out) {
  const std::vector<uint32_t> runs = ParseRleCounts(counts);
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

cv::Mat DecodeImage(const image& message, const std::string& field) {
  std::string problem;
  if (message.size == 0) throw FeedError("the scene has no " + field + " image");
  if (!CheckEncodedImageDims(message, &problem)) throw FeedError(field + ": " + problem);
  const bool sixteen = message.pixel_format == image::PIXEL_DEPTH16 ||
                       message.pixel_format == image::PIXEL_INSTANCE16;
  const bool rgb = message.pixel_format == image::PIXEL_RGB8;
  const int type = sixteen ? CV_16UC1 : rgb ? CV_8UC3 : CV_8UC1;
  if (message.encoding == image::ENCODING_RAW) {
    // little-endian 16-bit values are this machine's order (x86-64, arm64)
    return cv::Mat(message.height, message.width, type, const_cast<uint8_t*>(message.data.data()));
  }
  const cv::Mat bytes(1, message.size, CV_8UC1, const_cast<uint8_t*>(message.data.data()));
  cv::Mat decoded;
  try {
    decoded = cv::imdecode(bytes, sixteen ? cv::IMREAD_UNCHANGED
                                  : rgb   ? cv::IMREAD_COLOR
                                          : cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception& error) {
    throw FeedError(field + " does not decode: " + error.what());
  }
  if (decoded.empty() || decoded.type() != type || decoded.rows != message.height ||
      decoded.cols != message.width) {
    throw FeedError(field + " does not decode to a " + std::to_string(message.width) + "x" +
                    std::to_string(message.height) + " image of its pixel_format");
  }
  if (rgb) cv::cvtColor(decoded, decoded, cv::COLOR_BGR2RGB);
  return decoded;
}

bool CheckScene(const scene& message, std::string* why) {
  // the camera
  const camera_info& camera = message.camera;
  const int width = camera.width, height = camera.height;
  if (width <= 0 || height <= 0 || int64_t{width} * height > DecodeLimits{}.max_image_pixels) {
    return Refuse("camera is " + std::to_string(width) + "x" + std::to_string(height), why);
  }
  const double intrinsics[5] = {camera.fx, camera.fy, camera.cx, camera.cy, camera.depth_scale_mm};
  if (!Finite(intrinsics, 5) || camera.fx <= 0 || camera.fy <= 0 || camera.depth_scale_mm <= 0) {
    return Refuse("camera fx, fy or depth_scale_mm is not a positive number", why);
  }
  if (!FinitePose(camera.world_from_camera)) {
    return Refuse("camera.world_from_camera is not finite", why);
  }

  // the images
  if (message.color.size == 0) return Refuse("the scene has no color image", why);
  if (message.instance_map.size == 0) return Refuse("the scene has no instance_map image", why);
  if (!CheckImage(message.color, "color", width, height, {image::PIXEL_RGB8, image::PIXEL_GRAY8},
                  why) ||
      !CheckImage(message.instance_map, "instance_map", width, height, {image::PIXEL_INSTANCE16},
                  why)) {
    return false;
  }
  if (message.depth.size > 0 &&
      !CheckImage(message.depth, "depth", width, height, {image::PIXEL_DEPTH16}, why)) {
    return false;
  }

  // the instances
  if (message.num_instances != static_cast<int32_t>(message.instances.size())) {
    return Refuse("num_instances " + std::to_string(message.num_instances) + " but " +
                      std::to_string(message.instances.size()) + " instances",
                  why);
  }
  const int64_t area = int64_t{width} * height;
  // the full masks of every instance, decoded (N x H x W bytes), must fit in memory
  if (static_cast<int64_t>(message.instances.size()) * area > kMaxMaskPixels) {
    return Refuse(std::to_string(message.instances.size()) + " instances of " +
                      std::to_string(width) + "x" + std::to_string(height) +
                      " pixels: more mask pixels than " + std::to_string(kMaxMaskPixels),
                  why);
  }
  std::set<int32_t> ids;
  for (size_t k = 0; k < message.instances.size(); ++k) {
    const instance& object = message.instances[k];
    const std::string name = "instances[" + std::to_string(k) + "]";
    if (object.instance_id < 1 || object.instance_id > kMaxInstanceId ||
        !ids.insert(object.instance_id).second) {
      return Refuse(name + ".instance_id " + std::to_string(object.instance_id) +
                        " is outside 1..65535 or repeated",
                    why);
    }
    if (object.class_id < 1) {
      return Refuse(name + ".class_id " + std::to_string(object.class_id) + " is not >= 1", why);
    }
    if (!FinitePose(object.camera_from_object) || !FinitePose(object.world_from_object) ||
        !Finite(object.posture_deg, 3) || !std::isfinite(object.visib_fract) ||
        object.visib_fract < 0 || object.visib_fract > 1) {
      return Refuse(name + " has a pose, posture or visib_fract that is not finite or in range",
                    why);
    }
    if (!BoxInside(object.bbox_obj, width, height) ||
        !BoxInside(object.bbox_visib, width, height)) {
      return Refuse(name + " has a box outside the image", why);
    }
    if (object.px_count_visib < 0 || object.px_count_visib > object.px_count_all) {
      return Refuse(name + ".px_count_visib " + std::to_string(object.px_count_visib) +
                        " is not in 0..px_count_all (" + std::to_string(object.px_count_all) + ")",
                    why);
    }
    if (object.annotated && object.ignored) {
      return Refuse(name + " is both annotated and ignored", why);
    }
    const std::pair<const std::string*, int32_t> masks[2] = {
        {&object.mask_visib_rle, object.px_count_visib},
        {&object.mask_obj_rle, object.px_count_all}};
    const char* fields[2] = {"mask_visib_rle", "mask_obj_rle"};
    for (int m = 0; m < 2; ++m) {
      std::string problem;
      const int64_t inside = MaskPixels(*masks[m].first, area, &problem);
      if (inside < 0) {
        return Refuse(
            name + "." + fields[m] + " is not a COCO RLE mask of the image: it " + problem, why);
      }
      if (inside != masks[m].second) {
        return Refuse(name + "." + fields[m] + " holds " + std::to_string(inside) +
                          " pixels, its count says " + std::to_string(masks[m].second),
                      why);
      }
    }
  }
  return true;
}

cv::Mat FeedScene::Decoded(std::optional<cv::Mat>* slot, const image& message,
                           const std::string& field) {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (!slot->has_value()) {
    try {
      *slot = DecodeImage(message, field);
    } catch (const FeedError& error) {
      throw FeedError("scene " + std::to_string(message_.header.generator_id) + "/" +
                      std::to_string(message_.header.seq) + ": " + error.what());
    }
  }
  return **slot;
}

void FeedScene::Prepare(bool color, bool depth, bool instance_map) {
  std::string why;
  try {
    if (color) Color();
    if (instance_map) InstanceMap();
    if (depth && has_depth()) Depth();
  } catch (const std::exception& error) {
    why = error.what();
  }
  if (!why.empty()) {
    Fail(why);
    return;
  }
  {
    const std::lock_guard<std::mutex> lock(prepared_mutex_);
    prepared_ = 1;
  }
  prepared_changed_.notify_all();
}

void FeedScene::Fail(const std::string& why) {
  {
    const std::lock_guard<std::mutex> lock(prepared_mutex_);
    prepared_ = 2;
    failure_ = why;
  }
  prepared_changed_.notify_all();
}

bool FeedScene::WaitPrepared(std::string* why) {
  std::unique_lock<std::mutex> lock(prepared_mutex_);
  prepared_changed_.wait(lock, [this] { return prepared_ != 0; });
  if (prepared_ == 2 && why != nullptr) *why = failure_;
  return prepared_ == 1;
}

cv::Mat FeedScene::Color() { return Decoded(&color_, message_.color, "color"); }
cv::Mat FeedScene::Depth() { return Decoded(&depth_, message_.depth, "depth"); }
cv::Mat FeedScene::InstanceMap() {
  return Decoded(&instance_map_, message_.instance_map, "instance_map");
}

}  // namespace stackgen::feed
