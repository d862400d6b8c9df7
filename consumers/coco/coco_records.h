#pragma once

// The records of a COCO instances file as stackgen-coco writes them: COCO's fields and
// stackgen's own labels beside them (docs/programs.md, "`stackgen-coco`" lists them).

#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <stackgen/scene.hpp>

namespace stackgen {

/// The polygons of a visible mask (CV_8UC1), as CocoWriterOptions::polygons says: one per outer
/// contour, through boundary pixel centres; a piece of one or two pixels as the square around
/// them.
nlohmann::json MaskPolygons(const cv::Mat& mask);

/// A scene's image record: id, file, size, and stackgen's own fields (ids, seed, camera).
nlohmann::json ImageRecord(const stackgen::scene& scene, int64_t image_id,
                           const std::string& file_name);

/// One instance's annotation record (id `id`, in image `image_id`): COCO's fields with
/// `segmentation` (RLE or polygons) and `crowd`, the full (amodal) mask and box, and stackgen's
/// labels (visibility, pixel counts, posture, poses).
nlohmann::json AnnotationRecord(const stackgen::instance& instance, int64_t id, int64_t image_id,
                                const stackgen::camera_info& camera, nlohmann::json segmentation,
                                bool crowd);

}  // namespace stackgen
