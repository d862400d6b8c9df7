#pragma once

// Hand-made stackgen::scene messages for the stackgen-coco and stackgen-view tests: 8 x 6 pixels,
// a few instances with rectangular visible masks.

#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stackgen/scene.hpp>

#include "gen/annotate/rle.h"
#include "tests/support/process.h"

namespace stackgen::testing {

/// A new empty folder under $TMPDIR (or /tmp), removed with everything in it at scope exit.
class ScopedTempDir {
 public:
  explicit ScopedTempDir(const std::string& prefix) : path_(MakeTempDir(prefix)) {}
  ~ScopedTempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  ScopedTempDir(const ScopedTempDir&) = delete;
  ScopedTempDir& operator=(const ScopedTempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

constexpr int kSceneWidth = 8;
constexpr int kSceneHeight = 6;

/// An instance of class `class_id` whose visible pixels are `visible` (in an 8 x 6 image) and
/// whose visible fraction is `visib_fract`: px_count_all = visible area / visib_fract rounded (0
/// when visib_fract is 0), its full mask the visible pixels plus as many more as that needs, the
/// first ones outside `visible` in column-major order. Annotated when visib_fract >= 0.3 and
/// something is visible, as the generator's default; never ignored (see Ignored).
inline stackgen::instance MakeInstance(int instance_id, int class_id, const std::string& name,
                                       const cv::Rect& visible, double visib_fract) {
  stackgen::instance instance{};
  instance.instance_id = instance_id;
  instance.class_id = class_id;
  instance.class_name = name;
  for (stackgen::pose* pose : {&instance.camera_from_object, &instance.world_from_object}) {
    for (int i = 0; i < 9; ++i) pose->rotation[i] = (i % 4 == 0) ? 1.0 : 0.0;
    pose->quaternion_wxyz[0] = 1.0;
  }
  instance.camera_from_object.translation_mm[2] = 400.0 + instance_id;
  instance.world_from_object.translation_mm[0] = 0.1 * instance_id;
  instance.posture_deg[0] = 10.0 * instance_id;
  // the visible mask
  cv::Mat mask = cv::Mat::zeros(kSceneHeight, kSceneWidth, CV_8UC1);
  mask(visible).setTo(255);
  instance.mask_visib_rle = EncodeRle(mask);
  instance.px_count_visib = visible.area();
  instance.px_count_all =
      visib_fract > 0 ? static_cast<int>(std::lround(visible.area() / visib_fract)) : 0;
  instance.visib_fract = visib_fract;
  instance.annotated = visib_fract >= 0.3 && visible.area() > 0;
  instance.ignored = false;
  // the full mask: the visible pixels and the first hidden ones, column by column
  cv::Mat full = mask.clone();
  int missing = instance.px_count_all - visible.area();
  for (int x = 0; x < kSceneWidth && missing > 0; ++x) {
    for (int y = 0; y < kSceneHeight && missing > 0; ++y) {
      if (full.at<uint8_t>(y, x) == 0) {
        full.at<uint8_t>(y, x) = 255;
        --missing;
      }
    }
  }
  if (missing > 0) throw std::invalid_argument("MakeInstance: px_count_all exceeds the image");
  instance.mask_obj_rle = EncodeRle(full);
  const int32_t box[4] = {visible.x, visible.y, visible.width, visible.height};
  const cv::Rect full_box = cv::boundingRect(full);
  const int32_t obj_box[4] = {full_box.x, full_box.y, full_box.width, full_box.height};
  for (int i = 0; i < 4; ++i) {
    instance.bbox_visib[i] = visible.area() > 0 ? box[i] : 0;
    instance.bbox_obj[i] = full_box.area() > 0 ? obj_box[i] : 0;
  }
  return instance;
}

/// `instance` as the generator marks it under the IGNORE occlusion rule: not annotated, ignored.
inline stackgen::instance Ignored(stackgen::instance instance) {
  instance.annotated = false;
  instance.ignored = true;
  return instance;
}

/// A scene of generator `generator_id` with a colour image whose pixel (x, y) is
/// (R, G, B) = (10 * x, 20 * y, seq), RAW RGB8 unless `encoding` says PNG or JPEG.
inline stackgen::scene MakeScene(int generator_id, int64_t seq,
                                 std::vector<stackgen::instance> instances,
                                 int8_t encoding = stackgen::image::ENCODING_RAW) {
  stackgen::scene scene{};
  scene.header.seq = seq;
  scene.header.generator_id = generator_id;
  scene.header.seed = 1000 * generator_id + seq;
  scene.header.utime = 1700000000000000 + seq;
  scene.camera.width = kSceneWidth;
  scene.camera.height = kSceneHeight;
  scene.camera.fx = scene.camera.fy = 500.0;
  scene.camera.cx = 3.5;
  scene.camera.cy = 2.5;
  for (int i = 0; i < 9; ++i) scene.camera.world_from_camera.rotation[i] = (i % 4 == 0) ? 1 : 0;
  scene.camera.world_from_camera.quaternion_wxyz[0] = 1.0;
  scene.camera.world_from_camera.translation_mm[2] = 500.0;
  scene.camera.depth_scale_mm = 0.1;
  scene.num_instances = static_cast<int32_t>(instances.size());
  scene.instances = std::move(instances);

  // the colour image, RGB order
  std::vector<uint8_t> rgb;
  for (int y = 0; y < kSceneHeight; ++y) {
    for (int x = 0; x < kSceneWidth; ++x) {
      rgb.push_back(static_cast<uint8_t>(10 * x));
      rgb.push_back(static_cast<uint8_t>(20 * y));
      rgb.push_back(static_cast<uint8_t>(seq));
    }
  }
  stackgen::image& color = scene.color;
  color.width = kSceneWidth;
  color.height = kSceneHeight;
  color.pixel_format = stackgen::image::PIXEL_RGB8;
  color.encoding = encoding;
  if (encoding == stackgen::image::ENCODING_RAW) {
    color.data = rgb;
  } else {
    // OpenCV encodes BGR
    cv::Mat bgr(kSceneHeight, kSceneWidth, CV_8UC3);
    for (int y = 0; y < kSceneHeight; ++y) {
      for (int x = 0; x < kSceneWidth; ++x) {
        const uint8_t* p = &rgb[3 * (y * kSceneWidth + x)];
        bgr.at<cv::Vec3b>(y, x) = cv::Vec3b(p[2], p[1], p[0]);
      }
    }
    cv::imencode(encoding == stackgen::image::ENCODING_PNG ? ".png" : ".jpg", bgr, color.data);
  }
  color.size = static_cast<int32_t>(color.data.size());

  // depth and instance map are not used by stackgen-coco; keep them valid and empty
  for (stackgen::image* image : {&scene.depth, &scene.instance_map}) {
    image->width = kSceneWidth;
    image->height = kSceneHeight;
    image->encoding = stackgen::image::ENCODING_PNG;
    image->size = 0;
  }
  scene.depth.pixel_format = stackgen::image::PIXEL_DEPTH16;
  scene.instance_map.pixel_format = stackgen::image::PIXEL_INSTANCE16;
  return scene;
}

/// Scene A: generator 0, seq 0, RAW RGB; instance 1 (connector) fully visible, instance 2 below
/// the 0.3 threshold, instance 3 (bolt) half visible. Listed out of instance-id order.
inline stackgen::scene SceneA() {
  return MakeScene(0, 0,
                   {MakeInstance(3, 2, "bolt", cv::Rect(5, 0, 3, 2), 0.5),
                    MakeInstance(1, 1, "connector", cv::Rect(1, 2, 3, 3), 1.0),
                    MakeInstance(2, 1, "connector", cv::Rect(0, 5, 2, 1), 0.1)});
}

/// Scene B: generator 0, seq 1, PNG; one connector covering the image.
inline stackgen::scene SceneB() {
  return MakeScene(0, 1, {MakeInstance(1, 1, "connector", cv::Rect(0, 0, 8, 6), 1.0)},
                   stackgen::image::ENCODING_PNG);
}

/// Scene C: generator 1, seq 0, RAW GRAY8; one bolt.
inline stackgen::scene SceneC() {
  stackgen::scene scene = MakeScene(1, 0, {MakeInstance(7, 2, "bolt", cv::Rect(2, 1, 1, 4), 0.3)});
  stackgen::image& color = scene.color;
  color.pixel_format = stackgen::image::PIXEL_GRAY8;
  color.data.assign(static_cast<size_t>(kSceneWidth * kSceneHeight), 77);
  color.size = static_cast<int32_t>(color.data.size());
  return scene;
}

/// Scene D: generator 2, seq 0, RAW RGB, as the generator writes it with the IGNORE occlusion
/// rule: instance 1 annotated (visible fraction 0.8), instance 2 ignored (0.2, an ignore region),
/// instance 3 neither (nothing visible).
inline stackgen::scene SceneD() {
  return MakeScene(2, 0,
                   {MakeInstance(1, 1, "connector", cv::Rect(0, 0, 4, 2), 0.8),
                    Ignored(MakeInstance(2, 1, "connector", cv::Rect(5, 3, 2, 2), 0.2)),
                    MakeInstance(3, 2, "bolt", cv::Rect(0, 0, 0, 0), 0.0)});
}

}  // namespace stackgen::testing
