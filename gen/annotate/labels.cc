#include "gen/annotate/labels.h"

#include <algorithm>
#include <set>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "gen/annotate/pose.h"
#include "gen/annotate/rle.h"

namespace stackgen {
namespace {

std::string SizeText(const cv::Mat& image) {
  return std::to_string(image.cols) + " x " + std::to_string(image.rows);
}

// [x, y, width, height] of the nonzero pixels of a CV_8UC1 mask, all zero when there are none
void BoxOfMask(const cv::Mat& mask, int32_t box[4]) {
  const cv::Rect rect = cv::boundingRect(mask);
  box[0] = rect.x;
  box[1] = rect.y;
  box[2] = rect.width;
  box[3] = rect.height;
  if (rect.area() == 0) std::fill(box, box + 4, 0);
}

// Throws unless the inputs agree: a CV_16UC1 instance map, a CV_8UC1 silhouette of its size per
// object (and a larger beyond canvas, or none), instance ids 1..65535 once each, min_visib_fract
// in [0, 1].
void CheckLabelInputs(const cv::Mat& instance_map, const std::vector<cv::Mat>& silhouettes,
                      const std::vector<cv::Mat>& beyond, const std::vector<ObjectTruth>& objects,
                      double min_visib_fract) {
  if (instance_map.type() != CV_16UC1) {
    throw std::runtime_error("LabelInstances: instance_map must be CV_16UC1, got type " +
                             std::to_string(instance_map.type()));
  }
  if (silhouettes.size() != objects.size()) {
    throw std::runtime_error("LabelInstances: " + std::to_string(silhouettes.size()) +
                             " silhouettes for " + std::to_string(objects.size()) + " objects");
  }
  if (!beyond.empty() && beyond.size() != objects.size()) {
    throw std::runtime_error("LabelInstances: " + std::to_string(beyond.size()) +
                             " beyond masks for " + std::to_string(objects.size()) + " objects");
  }
  if (!(min_visib_fract >= 0.0 && min_visib_fract <= 1.0)) {
    throw std::runtime_error("LabelInstances: min_visib_fract " + std::to_string(min_visib_fract) +
                             " outside [0, 1]");
  }
  std::set<int> seen_ids;
  for (size_t i = 0; i < objects.size(); ++i) {
    const std::string name = "LabelInstances: objects[" + std::to_string(i) + "]";
    const int id = objects[i].instance_id;
    if (id < 1 || id > 65535) {
      throw std::runtime_error(name + ".instance_id " + std::to_string(id) + " outside 1..65535");
    }
    if (!seen_ids.insert(id).second) {
      throw std::runtime_error(name + ".instance_id " + std::to_string(id) + " repeated");
    }
    const cv::Mat& silhouette = silhouettes[i];
    if (silhouette.type() != CV_8UC1 || silhouette.size() != instance_map.size()) {
      throw std::runtime_error("LabelInstances: silhouettes[" + std::to_string(i) +
                               "] must be CV_8UC1 of " + SizeText(instance_map) +
                               " like instance_map, got type " + std::to_string(silhouette.type()) +
                               " of " + SizeText(silhouette));
    }
    if (beyond.empty() || beyond[i].empty()) continue;
    const cv::Mat& canvas = beyond[i];
    const int margin_x = canvas.cols - instance_map.cols;
    const int margin_y = canvas.rows - instance_map.rows;
    if (canvas.type() != CV_8UC1 || margin_x < 0 || margin_y < 0 || margin_x % 2 != 0 ||
        margin_y % 2 != 0) {
      throw std::runtime_error("LabelInstances: beyond[" + std::to_string(i) +
                               "] must be CV_8UC1 and larger than " + SizeText(instance_map) +
                               " by an even number of pixels each way, got type " +
                               std::to_string(canvas.type()) + " of " + SizeText(canvas));
    }
  }
}

// Adds the part of an object's silhouette outside the image (`canvas`: the image of
// `image_size` in the middle of a larger one; `outside` is scratch) to its px_count_all and
// bbox_obj.
void AddBeyond(const cv::Mat& canvas, const cv::Size& image_size, cv::Mat* outside,
               stackgen::instance* label) {
  const cv::Point image_corner((canvas.cols - image_size.width) / 2,
                               (canvas.rows - image_size.height) / 2);
  *outside = canvas.clone();
  (*outside)(cv::Rect(image_corner, image_size)).setTo(0);
  const int outside_pixels = cv::countNonZero(*outside);
  if (outside_pixels > 0) {
    cv::Rect box = cv::boundingRect(*outside) - image_corner;
    if (label->px_count_all > 0) {
      box |=
          cv::Rect(label->bbox_obj[0], label->bbox_obj[1], label->bbox_obj[2], label->bbox_obj[3]);
    }
    label->px_count_all += outside_pixels;
    label->bbox_obj[0] = box.x;
    label->bbox_obj[1] = box.y;
    label->bbox_obj[2] = box.width;
    label->bbox_obj[3] = box.height;
  }
}

}  // namespace

std::vector<stackgen::instance> LabelInstances(const cv::Mat& instance_map,
                                               const std::vector<cv::Mat>& silhouettes,
                                               const std::vector<cv::Mat>& beyond,
                                               const std::vector<ObjectTruth>& objects,
                                               const Eigen::Isometry3d& world_from_camera,
                                               double min_visib_fract, bool ignore_occluded,
                                               int min_visible_px) {
  CheckLabelInputs(instance_map, silhouettes, beyond, objects, min_visib_fract);

  const Eigen::Isometry3d camera_from_world = world_from_camera.inverse();
  std::vector<stackgen::instance> instances;
  instances.reserve(objects.size());
  cv::Mat visible, outside;
  for (size_t i = 0; i < objects.size(); ++i) {
    const ObjectTruth& object = objects[i];
    stackgen::instance label{};
    label.instance_id = object.instance_id;
    label.class_id = object.class_id;
    label.class_name = object.class_name;

    // poses and posture
    label.world_from_object = ToPoseMessage(object.world_from_object);
    label.camera_from_object = ToPoseMessage(camera_from_world * object.world_from_object);
    const Eigen::Vector3d posture = PostureAnglesDeg(object.world_from_object.linear());
    for (int k = 0; k < 3; ++k) label.posture_deg[k] = posture[k];
    label.resting_face = object.resting_face;

    // the whole object from its silhouette: in the image, and beyond its edges
    label.px_count_all = cv::countNonZero(silhouettes[i]);
    BoxOfMask(silhouettes[i], label.bbox_obj);
    label.mask_obj_rle = EncodeRle(silhouettes[i]);
    if (!beyond.empty() && !beyond[i].empty()) {
      AddBeyond(beyond[i], instance_map.size(), &outside, &label);
    }

    // the visible part from the instance map
    cv::compare(instance_map, cv::Scalar(object.instance_id), visible, cv::CMP_EQ);
    label.px_count_visib = cv::countNonZero(visible);
    BoxOfMask(visible, label.bbox_visib);
    label.mask_visib_rle = EncodeRle(visible);

    // how much is visible, and whether that is enough
    label.visib_fract =
        label.px_count_all > 0
            ? std::min(1.0, static_cast<double>(label.px_count_visib) / label.px_count_all)
            : 0.0;
    label.annotated =
        label.visib_fract >= min_visib_fract && label.px_count_visib >= std::max(1, min_visible_px);
    label.ignored = !label.annotated && label.px_count_visib > 0 && ignore_occluded;
    instances.push_back(std::move(label));
  }
  return instances;
}

}  // namespace stackgen
