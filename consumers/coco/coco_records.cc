#include "consumers/coco/coco_records.h"

#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

using nlohmann::json;

// a pose as stackgen's fields of a COCO record give it
json PoseJson(const stackgen::pose& pose) {
  return {{"translation_mm", std::vector<double>(pose.translation_mm, pose.translation_mm + 3)},
          {"rotation", std::vector<double>(pose.rotation, pose.rotation + 9)},
          {"quaternion_wxyz", std::vector<double>(pose.quaternion_wxyz, pose.quaternion_wxyz + 4)}};
}

}  // namespace

// The polygons of a visible mask (CV_8UC1), as CocoWriterOptions::polygons says: one per outer
// contour, through boundary pixel centres; a piece of one or two pixels as the square around them.
json MaskPolygons(const cv::Mat& mask) {
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(mask.clone(), contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
  json polygons = json::array();
  for (const std::vector<cv::Point>& contour : contours) {
    std::vector<double> points;
    if (contour.size() >= 3) {
      for (const cv::Point& point : contour) {
        points.push_back(point.x + 0.5);
        points.push_back(point.y + 0.5);
      }
    } else {
      const cv::Rect box = cv::boundingRect(contour);
      points = {static_cast<double>(box.x),
                static_cast<double>(box.y),
                static_cast<double>(box.x + box.width),
                static_cast<double>(box.y),
                static_cast<double>(box.x + box.width),
                static_cast<double>(box.y + box.height),
                static_cast<double>(box.x),
                static_cast<double>(box.y + box.height)};
    }
    polygons.push_back(std::move(points));
  }
  return polygons;
}

// a scene's image record: id, file, size, and stackgen's own fields (ids, seed, camera)
json ImageRecord(const stackgen::scene& scene, int64_t image_id, const std::string& file_name) {
  const stackgen::camera_info& camera = scene.camera;
  json camera_json = {{"fx", camera.fx},
                      {"fy", camera.fy},
                      {"cx", camera.cx},
                      {"cy", camera.cy},
                      {"world_from_camera", PoseJson(camera.world_from_camera)},
                      {"depth_scale_mm", camera.depth_scale_mm}};
  return {{"id", image_id},
          {"file_name", file_name},
          {"width", camera.width},
          {"height", camera.height},
          {"stackgen",
           {{"seq", scene.header.seq},
            {"generator_id", scene.header.generator_id},
            {"seed", scene.header.seed},
            {"camera", std::move(camera_json)}}}};
}

// one instance's annotation record: COCO's fields, the full (amodal) mask and box, and
// stackgen's labels (visibility, pixel counts, posture, poses)
json AnnotationRecord(const stackgen::instance& instance, int64_t id, int64_t image_id,
                      const stackgen::camera_info& camera, json segmentation, bool crowd) {
  const stackgen::pose& camera_from_object = instance.camera_from_object;
  const stackgen::pose& world_from_object = instance.world_from_object;
  return {{"id", id},
          {"image_id", image_id},
          {"category_id", instance.class_id},
          {"segmentation", std::move(segmentation)},
          {"area", instance.px_count_visib},
          {"bbox", std::vector<int32_t>(instance.bbox_visib, instance.bbox_visib + 4)},
          {"iscrowd", crowd ? 1 : 0},
          {"amodal_segmentation",
           {{"size", {camera.height, camera.width}}, {"counts", instance.mask_obj_rle}}},
          {"amodal_bbox", std::vector<int32_t>(instance.bbox_obj, instance.bbox_obj + 4)},
          {"instance_id", instance.instance_id},
          {"visib_fract", instance.visib_fract},
          {"px_count_all", instance.px_count_all},
          {"px_count_visib", instance.px_count_visib},
          {"bbox_obj", std::vector<int32_t>(instance.bbox_obj, instance.bbox_obj + 4)},
          {"posture_deg", std::vector<double>(instance.posture_deg, instance.posture_deg + 3)},
          {"resting_face", instance.resting_face},
          {"cam_R_m2c",
           std::vector<double>(camera_from_object.rotation, camera_from_object.rotation + 9)},
          {"cam_t_m2c", std::vector<double>(camera_from_object.translation_mm,
                                            camera_from_object.translation_mm + 3)},
          {"world_R_m2w",
           std::vector<double>(world_from_object.rotation, world_from_object.rotation + 9)},
          {"world_t_m2w", std::vector<double>(world_from_object.translation_mm,
                                              world_from_object.translation_mm + 3)}};
}

}  // namespace stackgen
