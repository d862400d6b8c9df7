#include "consumers/bop/model_files.h"

#include <algorithm>
#include <cstdio>
#include <limits>

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

}  // namespace stackgen
