#include "contract/scene_contract.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <set>
#include <stdexcept>
#include <vector>

#include "contract/bounded_decode.h"
#include "contract/rle.h"

namespace stackgen {
namespace {

bool Refuse(const std::string& text, std::string* why) {
  if (why != nullptr) *why = text;
  return false;
}

std::string Number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

// every value of `values` finite; else names the first that is not: "<field>[k] is not finite"
bool CheckFinite(const double* values, int count, const std::string& field, std::string* why) {
  for (int k = 0; k < count; ++k) {
    if (!std::isfinite(values[k])) {
      return Refuse(field + "[" + std::to_string(k) + "] is not finite", why);
    }
  }
  return true;
}

bool CheckPose(const pose& p, const std::string& field, std::string* why) {
  return CheckFinite(p.translation_mm, 3, field + ".translation_mm", why) &&
         CheckFinite(p.rotation, 9, field + ".rotation", why) &&
         CheckFinite(p.quaternion_wxyz, 4, field + ".quaternion_wxyz", why);
}

// an image of the scene: format, the camera's size, its bytes and encoding, its file header
bool CheckImage(const image& m, const std::string& field, int width, int height,
                std::initializer_list<int8_t> formats, const char* format_names, std::string* why) {
  bool known = false;
  for (const int8_t format : formats) known = known || m.pixel_format == format;
  if (!known) {
    return Refuse(
        field + ".pixel_format " + std::to_string(m.pixel_format) + " is not " + format_names, why);
  }
  if (m.width != width || m.height != height) {
    return Refuse(field + ".width x " + field + ".height " + std::to_string(m.width) + " x " +
                      std::to_string(m.height) + " differs from camera " + std::to_string(width) +
                      " x " + std::to_string(height),
                  why);
  }
  if (m.size < 0 || static_cast<size_t>(m.size) != m.data.size()) {
    return Refuse(field + ".size " + std::to_string(m.size) + " differs from the " +
                      std::to_string(m.data.size()) + " bytes of " + field + ".data",
                  why);
  }
  if (m.encoding != image::ENCODING_RAW && m.encoding != image::ENCODING_PNG &&
      m.encoding != image::ENCODING_JPEG) {
    return Refuse(field + ".encoding " + std::to_string(m.encoding) + " is not RAW, PNG or JPEG",
                  why);
  }
  std::string problem;
  if (!CheckEncodedImageDims(m, &problem)) {
    return Refuse(field + (m.encoding == image::ENCODING_RAW ? ".size: " : ".data: ") + problem,
                  why);
  }
  return true;
}

// whether a box [x, y, w, h] lies inside a width x height image
bool BoxInside(const int32_t box[4], int width, int height) {
  return box[0] >= 0 && box[1] >= 0 && box[2] >= 0 && box[3] >= 0 &&
         int64_t{box[0]} + box[2] <= width && int64_t{box[1]} + box[3] <= height;
}

std::string BoxText(const int32_t box[4]) {
  return "[" + std::to_string(box[0]) + ", " + std::to_string(box[1]) + ", " +
         std::to_string(box[2]) + ", " + std::to_string(box[3]) + "]";
}

// a box [x, y, w, h] inside a width x height image
bool CheckBox(const int32_t box[4], const std::string& field, int width, int height,
              std::string* why) {
  if (BoxInside(box, width, height)) return true;
  return Refuse(field + " " + BoxText(box) + " is not inside the " + std::to_string(width) + " x " +
                    std::to_string(height) + " image",
                why);
}

// the box [x, y, w, h] of a whole silhouette: it may reach past the image's edges, by at most
// the image's size each way (the canvas the generator draws it on, as bop_toolkit's)
bool CheckAmodalBox(const int32_t box[4], const std::string& field, int width, int height,
                    std::string* why) {
  if (box[0] >= -width && box[1] >= -height && box[2] >= 0 && box[3] >= 0 &&
      int64_t{box[0]} + box[2] <= 2 * int64_t{width} &&
      int64_t{box[1]} + box[3] <= 2 * int64_t{height}) {
    return true;
  }
  return Refuse(field + " " + BoxText(box) + " reaches more than the image's size past the " +
                    std::to_string(width) + " x " + std::to_string(height) + " image",
                why);
}

// a mask over the image holding `expected` pixels (the value of `count_field`), or at most that
// many when `at_most`
bool CheckMask(const std::string& counts, int32_t expected, int64_t area, const std::string& field,
               const std::string& count_field, std::string* why, bool at_most = false) {
  std::string problem;
  const int64_t pixels = MaskPixels(counts, area, &problem);
  if (pixels < 0) return Refuse(field + " " + problem, why);
  if (at_most ? pixels > expected : pixels != expected) {
    return Refuse(field + " holds " + std::to_string(pixels) + " pixels, " + count_field + " is " +
                      std::to_string(expected),
                  why);
  }
  return true;
}

// The camera: a size within the decode limits, positive focal lengths and depth scale, a finite
// principal point and pose.
bool CheckCamera(const camera_info& camera, std::string* why) {
  const int width = camera.width, height = camera.height;
  if (width <= 0 || height <= 0 || int64_t{width} * height > DecodeLimits{}.max_image_pixels) {
    return Refuse("camera.width x camera.height " + std::to_string(width) + " x " +
                      std::to_string(height) + " is not a positive size of at most " +
                      std::to_string(DecodeLimits{}.max_image_pixels) + " pixels",
                  why);
  }
  const std::pair<const char*, double> positive[3] = {
      {"camera.fx", camera.fx},
      {"camera.fy", camera.fy},
      {"camera.depth_scale_mm", camera.depth_scale_mm}};
  for (const auto& [field, value] : positive) {
    if (!(std::isfinite(value) && value > 0)) {
      return Refuse(std::string(field) + " " + Number(value) + " is not a positive number", why);
    }
  }
  const double principal[2] = {camera.cx, camera.cy};
  if (!CheckFinite(principal, 2, "camera.cx, camera.cy", why) ||
      !CheckPose(camera.world_from_camera, "camera.world_from_camera", why)) {
    return false;
  }
  return true;
}

// The images of `message`: colour always, depth, the instance map and the sensor's depth when
// sent, each of the camera's size and of a pixel format it may have.
bool CheckImages(const scene& message, std::string* why) {
  const int width = message.camera.width, height = message.camera.height;
  if (message.color.size == 0) return Refuse("the scene has no color image", why);
  if (!CheckImage(message.color, "color", width, height, {image::PIXEL_RGB8, image::PIXEL_GRAY8},
                  "RGB8 or GRAY8", why)) {
    return false;
  }
  if (message.depth.size != 0 &&
      !CheckImage(message.depth, "depth", width, height, {image::PIXEL_DEPTH16}, "DEPTH16", why)) {
    return false;
  }
  if (message.instance_map.size != 0 &&
      !CheckImage(message.instance_map, "instance_map", width, height, {image::PIXEL_INSTANCE16},
                  "INSTANCE16", why)) {
    return false;
  }
  if (message.depth_sensor.size != 0 &&
      !CheckImage(message.depth_sensor, "depth_sensor", width, height, {image::PIXEL_DEPTH16},
                  "DEPTH16", why)) {
    return false;
  }
  return true;
}

// One instance (`field` names it) after its id: class, poses, visibility, pixel counts, boxes
// and masks, and the generator's label.
bool CheckInstance(const instance& object, const std::string& field, int width, int height,
                   std::string* why) {
  const int64_t area = int64_t{width} * height;
  if (object.class_id < 1) {
    return Refuse(field + ".class_id " + std::to_string(object.class_id) + " is not >= 1", why);
  }
  if (object.class_name.empty()) return Refuse(field + ".class_name is empty", why);
  if (!CheckPose(object.camera_from_object, field + ".camera_from_object", why) ||
      !CheckPose(object.world_from_object, field + ".world_from_object", why) ||
      !CheckFinite(object.posture_deg, 3, field + ".posture_deg", why)) {
    return false;
  }
  if (!(object.visib_fract >= 0.0 && object.visib_fract <= 1.0)) {
    return Refuse(field + ".visib_fract " + Number(object.visib_fract) + " outside [0, 1]", why);
  }
  if (object.px_count_visib < 0 || object.px_count_visib > object.px_count_all) {
    return Refuse(field + ".px_count_visib " + std::to_string(object.px_count_visib) +
                      " is not in 0..px_count_all (" + std::to_string(object.px_count_all) + ")",
                  why);
  }
  // the whole silhouette may reach past the image's edges (bbox_obj and px_count_all count
  // that part too); its mask holds the part in the image, all of it when bbox_obj lies inside
  const bool whole_in_image = BoxInside(object.bbox_obj, width, height);
  if (!CheckAmodalBox(object.bbox_obj, field + ".bbox_obj", width, height, why) ||
      !CheckBox(object.bbox_visib, field + ".bbox_visib", width, height, why) ||
      !CheckMask(object.mask_visib_rle, object.px_count_visib, area, field + ".mask_visib_rle",
                 "px_count_visib", why) ||
      !CheckMask(object.mask_obj_rle, object.px_count_all, area, field + ".mask_obj_rle",
                 "px_count_all", why, !whole_in_image)) {
    return false;
  }
  // the generator's label: annotated, ignored or neither; both need visible pixels
  if (object.annotated && object.ignored) {
    return Refuse(field + ".ignored and " + field + ".annotated are both true", why);
  }
  if ((object.annotated || object.ignored) && object.px_count_visib == 0) {
    return Refuse(
        field + (object.annotated ? ".annotated" : ".ignored") + " is true but px_count_visib is 0",
        why);
  }
  return true;
}

}  // namespace

int64_t MaskPixels(const std::string& counts, int64_t image_pixels, std::string* why) {
  const auto refuse = [why](const std::string& text) -> int64_t {
    if (why != nullptr) *why = text;
    return -1;
  };
  if (counts.empty()) return refuse("is empty");
  std::vector<uint32_t> runs;
  try {
    runs = StringToRuns(counts);
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

// The fields both kinds of grasps share: a known instance, a rank, a pixel of the image, lengths
// that are finite and not negative, a known proof, moved instances that are the scene's.
template <typename Grasp>
bool CheckGraspCommon(const Grasp& grasp, const std::string& field, const std::set<int32_t>& ids,
                      const camera_info& camera, std::string* why) {
  if (ids.count(grasp.instance_id) == 0) {
    return Refuse(field + ".instance_id " + std::to_string(grasp.instance_id) +
                      " is no instance of the scene",
                  why);
  }
  if (grasp.rank < 0) return Refuse(field + ".rank " + std::to_string(grasp.rank) + " < 0", why);
  if (grasp.u < 0 || grasp.v < 0 || grasp.u >= camera.width || grasp.v >= camera.height) {
    return Refuse(field + ".u, v (" + std::to_string(grasp.u) + ", " + std::to_string(grasp.v) +
                      ") outside the image",
                  why);
  }
  const std::pair<const char*, double> lengths[4] = {
      {"clearance_mm", grasp.clearance_mm},
      {"com_offset_mm", grasp.com_offset_mm},
      {"proof_swing_deg", grasp.proof_swing_deg},
      {"proof_neighbours_moved_mm", grasp.proof_neighbours_moved_mm}};
  for (const auto& [name, value] : lengths) {
    if (!(std::isfinite(value) && value >= 0)) {
      return Refuse(field + "." + name + " " + Number(value) + " is not a finite number >= 0",
                    why);
    }
  }
  if (grasp.proof < suction_grasp::PROOF_NOT_TRIED || grasp.proof > suction_grasp::PROOF_STUCK) {
    return Refuse(field + ".proof " + std::to_string(grasp.proof) + " is not 0..3", why);
  }
  if (grasp.num_moved < 0) {
    return Refuse(field + ".num_moved " + std::to_string(grasp.num_moved) + " < 0", why);
  }
  for (int m = 0; m < std::min(grasp.num_moved, 8); ++m) {
    if (ids.count(grasp.moved_instance_ids[m]) == 0) {
      return Refuse(field + ".moved_instance_ids[" + std::to_string(m) + "] " +
                        std::to_string(grasp.moved_instance_ids[m]) +
                        " is no instance of the scene",
                    why);
    }
  }
  return true;
}

// whether `values` (3) is a unit vector; refuses naming `field` when not
bool CheckUnit(const double* values, const std::string& field, std::string* why) {
  if (!CheckFinite(values, 3, field, why)) return false;
  const double length =
      std::sqrt(values[0] * values[0] + values[1] * values[1] + values[2] * values[2]);
  if (std::abs(length - 1) > 1e-3) {
    return Refuse(field + " has length " + Number(length) + ", not 1", why);
  }
  return true;
}

// The grasps: their counts, each on a known instance, a pixel of the image, unit directions,
// scores in range and a known proof.
bool CheckGrasps(const scene& message, const std::set<int32_t>& ids, std::string* why) {
  const auto count_matches = [&](int32_t count, size_t size, const char* name) {
    if (count >= 0 && static_cast<size_t>(count) == size) return true;
    return Refuse(std::string("num_") + name + " " + std::to_string(count) + " differs from the " +
                      std::to_string(size) + " entries of " + name,
                  why);
  };
  if (!count_matches(message.num_suction_grasps, message.suction_grasps.size(),
                     "suction_grasps") ||
      !count_matches(message.num_jaw_grasps, message.jaw_grasps.size(), "jaw_grasps")) {
    return false;
  }
  for (size_t k = 0; k < message.suction_grasps.size(); ++k) {
    const suction_grasp& grasp = message.suction_grasps[k];
    const std::string field = "suction_grasps[" + std::to_string(k) + "]";
    if (!CheckGraspCommon(grasp, field, ids, message.camera, why) ||
        !CheckFinite(grasp.point_mm, 3, field + ".point_mm", why) ||
        !CheckUnit(grasp.normal, field + ".normal", why)) {
      return false;
    }
    if (!(grasp.seal >= 0 && grasp.seal <= 1)) {
      return Refuse(field + ".seal " + Number(grasp.seal) + " outside [0, 1]", why);
    }
  }
  for (size_t k = 0; k < message.jaw_grasps.size(); ++k) {
    const jaw_grasp& grasp = message.jaw_grasps[k];
    const std::string field = "jaw_grasps[" + std::to_string(k) + "]";
    if (!CheckGraspCommon(grasp, field, ids, message.camera, why) ||
        !CheckFinite(grasp.point_a_mm, 3, field + ".point_a_mm", why) ||
        !CheckFinite(grasp.point_b_mm, 3, field + ".point_b_mm", why) ||
        !CheckUnit(grasp.approach, field + ".approach", why)) {
      return false;
    }
    if (!(std::isfinite(grasp.width_mm) && grasp.width_mm > 0) ||
        !(std::isfinite(grasp.cone_margin_deg) && grasp.cone_margin_deg >= 0)) {
      return Refuse(field + ".width_mm " + Number(grasp.width_mm) + " and cone_margin_deg " +
                        Number(grasp.cone_margin_deg) + " must be finite, > 0 and >= 0",
                    why);
    }
  }
  return true;
}

bool CheckScene(const scene& message, std::string* why) {
  // the header
  if (message.header.generator_id < 0 || message.header.generator_id > kMaxGeneratorId) {
    return Refuse("header.generator_id " + std::to_string(message.header.generator_id) +
                      " outside 0.." + std::to_string(kMaxGeneratorId),
                  why);
  }
  if (message.header.seq < 0 || message.header.seq > kMaxSeq) {
    return Refuse("header.seq " + std::to_string(message.header.seq) + " outside 0.." +
                      std::to_string(kMaxSeq),
                  why);
  }

  // the camera and the images: colour always, depth and the instance map when sent
  const int width = message.camera.width, height = message.camera.height;
  if (!CheckCamera(message.camera, why) || !CheckImages(message, why)) return false;

  // the instances
  if (message.num_instances < 0 ||
      static_cast<size_t>(message.num_instances) != message.instances.size()) {
    return Refuse("num_instances " + std::to_string(message.num_instances) + " differs from the " +
                      std::to_string(message.instances.size()) + " entries of instances",
                  why);
  }
  const int64_t area = int64_t{width} * height;
  if (static_cast<int64_t>(message.instances.size()) * area > kMaxSceneMaskPixels) {
    return Refuse(std::to_string(message.instances.size()) + " instances of " +
                      std::to_string(width) + " x " + std::to_string(height) +
                      " pixels: more mask pixels than " + std::to_string(kMaxSceneMaskPixels),
                  why);
  }
  std::set<int32_t> ids;
  for (size_t k = 0; k < message.instances.size(); ++k) {
    const instance& object = message.instances[k];
    const std::string field = "instances[" + std::to_string(k) + "]";
    if (object.instance_id < 1 || object.instance_id > kMaxInstanceId) {
      return Refuse(field + ".instance_id " + std::to_string(object.instance_id) + " outside 1.." +
                        std::to_string(kMaxInstanceId),
                    why);
    }
    if (!ids.insert(object.instance_id).second) {
      return Refuse(field + ".instance_id " + std::to_string(object.instance_id) + " repeated",
                    why);
    }
    if (!CheckInstance(object, field, width, height, why)) return false;
  }
  return CheckGrasps(message, ids, why);
}

}  // namespace stackgen
