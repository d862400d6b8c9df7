#pragma once

// A model's files in a BOP dataset: its mesh as models/obj_OBJ_ID.ply and its entry of
// models/models_info.json; and an image's depth as a point cloud.

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <stackgen/camera_info.hpp>
#include <stackgen/model.hpp>

namespace stackgen {

/// The model as an ASCII PLY file in millimetres, with normals (BOP's models all have them);
/// 9 significant digits give every float back exactly.
std::string PlyText(const model& m);

/// The model's entry of models_info.json: diameter, bounding box, and its discrete and
/// continuous symmetries where it has any.
nlohmann::json ModelInfo(const model& m);

/// A depth image (CV_16UC1, depth_mm = value x camera.depth_scale_mm, 0 = no depth) as an
/// organised point cloud: a binary little-endian PLY of width x height vertices (float x, y, z
/// in millimetres, the OpenCV camera frame), row by row from the top left, NaN where there is no
/// depth, its size in the header as PCL writes organised clouds ("obj_info num_cols W",
/// "obj_info num_rows H"). Throws std::invalid_argument for another type or size.
std::vector<uint8_t> PointCloudPly(const cv::Mat& depth, const camera_info& camera);

}  // namespace stackgen
