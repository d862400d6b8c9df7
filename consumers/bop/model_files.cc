#include "consumers/bop/model_files.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace stackgen {

using nlohmann::json;

// the model as an ASCII PLY file in millimetres, with normals (BOP's models all have them)
std::string PlyText(const model& m) {
  std::string text = "ply\nformat ascii 1.0\ncomment stackgen model of class " +
                     std::to_string(m.class_id) + " (" + m.class_name + "), millimetres\n";
  text += "element vertex " + std::to_string(m.num_vertices) +
          "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\n"
          "property float ny\nproperty float nz\n";
  text += "element face " + std::to_string(m.num_triangles) +
          "\nproperty list uchar int vertex_indices\nend_header\n";
  char line[256];
  for (int32_t v = 0; v < m.num_vertices; ++v) {
    const std::vector<float>& p = m.vertices_mm[static_cast<size_t>(v)];
    const std::vector<float>& n = m.normals[static_cast<size_t>(v)];
    // 9 significant digits give every float back exactly
    std::snprintf(line, sizeof(line), "%.9g %.9g %.9g %.9g %.9g %.9g\n", p[0], p[1], p[2], n[0],
                  n[1], n[2]);
    text += line;
  }
  for (const std::vector<int32_t>& t : m.triangles) {
    std::snprintf(line, sizeof(line), "3 %d %d %d\n", t[0], t[1], t[2]);
    text += line;
  }
  return text;
}

// the model's entry of models_info.json
json ModelInfo(const model& m) {
  double low[3], high[3];
  for (int a = 0; a < 3; ++a) {
    low[a] = std::numeric_limits<double>::infinity();
    high[a] = -low[a];
  }
  for (const std::vector<float>& p : m.vertices_mm) {
    for (int a = 0; a < 3; ++a) {
      low[a] = std::min(low[a], static_cast<double>(p[a]));
      high[a] = std::max(high[a], static_cast<double>(p[a]));
    }
  }
  json info = {{"diameter", m.diameter_mm},
               {"min_x", low[0]},
               {"min_y", low[1]},
               {"min_z", low[2]},
               {"size_x", high[0] - low[0]},
               {"size_y", high[1] - low[1]},
               {"size_z", high[2] - low[2]}};
  if (!m.discrete_symmetries.empty()) info["symmetries_discrete"] = m.discrete_symmetries;
  if (!m.continuous_axes.empty()) {
    json continuous = json::array();
    for (size_t i = 0; i < m.continuous_axes.size(); ++i) {
      continuous.push_back(
          {{"axis", m.continuous_axes[i]}, {"offset", m.continuous_offsets_mm[i]}});
    }
    info["symmetries_continuous"] = std::move(continuous);
  }
  return info;
}

std::vector<uint8_t> PointCloudPly(const cv::Mat& depth, const camera_info& camera) {
  if (depth.type() != CV_16UC1 || depth.cols != camera.width || depth.rows != camera.height) {
    throw std::invalid_argument("PointCloudPly: the depth image must be CV_16UC1 of the camera's " +
                                std::to_string(camera.width) + " x " +
                                std::to_string(camera.height) + " pixels");
  }
  const std::string header =
      "ply\nformat binary_little_endian 1.0\ncomment stackgen depth, camera frame (OpenCV), "
      "millimetres; NaN = no depth\nobj_info num_cols " +
      std::to_string(depth.cols) + "\nobj_info num_rows " + std::to_string(depth.rows) +
      "\nelement vertex " + std::to_string(depth.total()) +
      "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  std::vector<uint8_t> bytes(header.begin(), header.end());
  bytes.resize(header.size() + depth.total() * 3 * sizeof(float));
  uint8_t* out = bytes.data() + header.size();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < depth.rows; ++v) {
    const uint16_t* row = depth.ptr<uint16_t>(v);
    for (int u = 0; u < depth.cols; ++u) {
      float point[3] = {nan, nan, nan};
      if (row[u] != 0) {
        const double z = row[u] * camera.depth_scale_mm;
        point[0] = static_cast<float>((u - camera.cx) * z / camera.fx);
        point[1] = static_cast<float>((v - camera.cy) * z / camera.fy);
        point[2] = static_cast<float>(z);
      }
      static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the PLY says little-endian");
      std::memcpy(out, point, sizeof(point));
      out += sizeof(point);
    }
  }
  return bytes;
}

}  // namespace stackgen
