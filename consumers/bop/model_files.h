#pragma once

// A model's files in a BOP dataset: its mesh as models/obj_OBJ_ID.ply and its entry of
// models/models_info.json.

#include <string>

#include <nlohmann/json.hpp>
#include <stackgen/model.hpp>

namespace stackgen {

/// The model as an ASCII PLY file in millimetres, with normals (BOP's models all have them);
/// 9 significant digits give every float back exactly.
std::string PlyText(const model& m);

/// The model's entry of models_info.json: diameter, bounding box, and its discrete and
/// continuous symmetries where it has any.
nlohmann::json ModelInfo(const model& m);

}  // namespace stackgen
