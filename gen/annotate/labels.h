#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <stackgen/instance.hpp>

namespace stackgen {

/// What the scene knows about one object before it is rendered.
struct ObjectTruth {
  /// Its value in the instance map (1..65535).
  int instance_id = 0;
  /// Class id (1-based) and name of the part type.
  int class_id = 0;
  std::string class_name;
  /// Object pose in the world (bin) frame, millimetres.
  Eigen::Isometry3d world_from_object = Eigen::Isometry3d::Identity();
  /// Index of the hull face that points down (see instance.lcm resting_face); -1 unknown.
  int resting_face = -1;
};

/// Labels every object from one render. `instance_map` is CV_16UC1 (0 = background, else the
/// instance_id of the object seen at the pixel); `silhouettes[i]` is the CV_8UC1 mask (nonzero
/// inside) of `objects[i]` drawn alone with the same camera; `beyond` is empty, or holds for each
/// object an empty Mat (nothing of it outside the image) or its silhouette on a canvas that
/// holds the image in its middle (CV_8UC1, (canvas - image size) even; pixels over the image
/// itself are not read: `silhouettes` has them), as Renderer::RenderSilhouettes makes it;
/// `world_from_camera` is the camera pose in millimetres (OpenCV camera frame). Fills both poses
/// (camera_from_object = camera_from_world * world_from_object), the posture angles,
/// px_count_all and bbox_obj over the whole silhouette, the part outside the image included (as
/// bop_toolkit: the box may start left of or above the image and reach past its edges),
/// bbox_visib (from instance_map == instance_id) as [x, y, width, height] pixels,
/// px_count_visib, visib_fract (0 when px_count_all is 0, at most 1), annotated = visib_fract >=
/// `min_visib_fract` and px_count_visib >= max(1, `min_visible_px`), ignored = not annotated,
/// px_count_visib > 0 and `ignore_occluded` (the IGNORE occlusion rule), mask_visib_rle (COCO
/// compressed RLE of instance_map == instance_id) and mask_obj_rle (of the silhouette in the
/// image). Returns one instance per object, in the order of `objects`. Throws std::runtime_error if
/// a type or size disagrees, silhouettes, beyond (when not empty) and objects differ in number, an
/// instance_id is outside 1..65535 or repeated, or min_visib_fract is outside [0, 1].
std::vector<stackgen::instance> LabelInstances(const cv::Mat& instance_map,
                                               const std::vector<cv::Mat>& silhouettes,
                                               const std::vector<cv::Mat>& beyond,
                                               const std::vector<ObjectTruth>& objects,
                                               const Eigen::Isometry3d& world_from_camera,
                                               double min_visib_fract, bool ignore_occluded,
                                               int min_visible_px = 1);

}  // namespace stackgen
