#include <LinearMath/btConvexHullComputer.h>

#include <sstream>
#include <stdexcept>
#include <string>

#include "gen/physics/convex_pieces.h"
#include "gen/physics/pile_internal.h"

namespace stackgen {
namespace pile_internal {
namespace {

// Turns convex pieces (object frame) into box or hull pieces in the body frame.
std::vector<Piece> MakePieces(const std::vector<std::vector<Eigen::Vector3d>>& pieces_mm,
                              const Eigen::Isometry3d& body_from_object) {
  std::vector<Piece> result;
  for (const auto& points : pieces_mm) {
    Box bounds;
    for (const auto& p : points) bounds.Add(p);
    const Eigen::Vector3d size = bounds.hi - bounds.lo;
    Piece piece;
    piece.margin_mm = std::min(kMarginMm, size.minCoeff() / 4);

    // an axis-aligned box collides best as a btBoxShape (box-box gives full contact manifolds)
    if (ConvexHullVolume(points) >= (1 - 1e-6) * size.prod()) {
      piece.is_box = true;
      piece.half_extents_mm = size / 2;
      piece.body_from_piece = body_from_object * Eigen::Translation3d((bounds.lo + bounds.hi) / 2);
      result.push_back(std::move(piece));
      continue;
    }

    // any other hull is shrunk by the margin Bullet adds around it
    std::vector<Eigen::Vector3d> body_points;
    for (const auto& p : points) body_points.push_back(body_from_object * p);
    btConvexHullComputer computer;
    const btScalar shrunk = computer.compute(
        body_points[0].data(), sizeof(Eigen::Vector3d), static_cast<int>(body_points.size()),
        static_cast<btScalar>(piece.margin_mm), static_cast<btScalar>(0.25));
    if (shrunk > 0 && computer.vertices.size() >= 4) {
      piece.margin_mm = shrunk;
      for (int i = 0; i < computer.vertices.size(); ++i) {
        const btVector3& v = computer.vertices[i];
        piece.points_mm.emplace_back(v.x(), v.y(), v.z());
      }
    } else {
      piece.margin_mm = 0;
      piece.points_mm = body_points;
    }
    result.push_back(std::move(piece));
  }
  return result;
}

}  // namespace

// Throws unless lo <= value <= hi (lo < value with `lo_open`).
void CheckRange(const char* object, const char* field, double value, double lo, double hi,
                bool lo_open) {
  if (!(std::isfinite(value) && (lo_open ? value > lo : value >= lo) && value <= hi)) {
    std::ostringstream message;
    message << "PileSimulator: " << object << "." << field << " must be in "
            << (lo_open ? "(" : "[") << lo << ", " << hi << "], got " << value;
    throw std::runtime_error(message.str());
  }
}

void CheckRange(const char* object, const char* field, double value, double lo, double hi) {
  CheckRange(object, field, value, lo, hi, false);
}

// Throws unless `value` is in the range the config schema states for `schema_field` of
// `message` (types/stackgen_config.proto): the simulator's ranges are the config's.
void CheckSchemaRange(const std::string& object, const char* field,
                      const google::protobuf::Descriptor* message, const char* schema_field,
                      double value) {
  const config::Range& range =
      message->FindFieldByName(schema_field)->options().GetExtension(config::range);
  CheckRange(object.c_str(), field, value, range.min(), range.max(), range.min_open());
}

// Builds a part type; errors start with `what`.
TypeModel MakeTypeModel(const PartType& type, const std::string& what,
                        const std::string& cache_dir) {
  const PartPhysics& physics = type.physics;
  const std::string object = what + "PartPhysics";
  const google::protobuf::Descriptor* part = config::PartConfig::descriptor();
  CheckSchemaRange(object, "density_kg_m3", part, "density_kg_m3", physics.density_kg_m3);
  CheckSchemaRange(object, "friction", part, "friction", physics.friction);
  CheckSchemaRange(object, "restitution", part, "restitution", physics.restitution);
  CheckSchemaRange(object, "rolling_friction_mm", part, "rolling_friction_mm",
                   physics.rolling_friction_mm);
  if (type.mesh.triangles.empty()) {
    throw std::runtime_error("PileSimulator: " + what + "the part mesh is empty");
  }
  TypeModel model;
  model.physics = physics;

  // mass properties from the closed mesh; the body frame is the principal frame at the centre
  // of mass
  model.mass = ComputeMassProperties(type.mesh, physics.density_kg_m3,
                                     "PileSimulator: " + what + "part mesh");
  model.body_from_object = model.mass.principal_from_object;
  model.object_from_body = model.body_from_object.inverse();

  // collision pieces, in the body frame
  ConvexPieces convex;
  try {
    convex = MakeConvexPieces(type.mesh, type.collision_pieces, cache_dir);
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("PileSimulator: " + what + e.what());
  }
  model.pieces = MakePieces(convex.points_mm, model.body_from_object);
  model.description = convex.description;

  // the part's hull: its vertices give each released part's bounding box, its faces the
  // resting face
  std::vector<Eigen::Vector3d> points;
  for (const auto& p : type.mesh.positions_mm) points.push_back(p.cast<double>());
  btConvexHullComputer computer;
  computer.compute(points[0].data(), sizeof(Eigen::Vector3d), static_cast<int>(points.size()), 0,
                   0);
  Box bounds;
  for (int i = 0; i < computer.vertices.size(); ++i) {
    model.hull_vertices_mm.push_back(points[computer.original_vertex_index[i]]);
    bounds.Add(model.hull_vertices_mm.back());
  }
  model.max_extent_mm = (bounds.hi - bounds.lo).maxCoeff();
  model.hull_faces = HullFaces(model.hull_vertices_mm);
  return model;
}

// Throws, naming the field, unless the bin's and the simulation's values are in range.
// (each range the config schema's; what depends on another value, here)
void CheckInputs(const BinSpec& bin, const SimulationParams& params) {
  const google::protobuf::Descriptor* b = config::BinConfig::descriptor();
  CheckSchemaRange("BinSpec", "inner_length_mm", b, "inner_length_mm", bin.inner_length_mm);
  CheckSchemaRange("BinSpec", "inner_width_mm", b, "inner_width_mm", bin.inner_width_mm);
  CheckSchemaRange("BinSpec", "inner_height_mm", b, "inner_height_mm", bin.inner_height_mm);
  CheckSchemaRange("BinSpec", "wall_mm", b, "wall_thickness_mm", bin.wall_mm);
  CheckSchemaRange("BinSpec", "friction", b, "friction", bin.friction);
  CheckSchemaRange("BinSpec", "restitution", b, "restitution", bin.restitution);
  const google::protobuf::Descriptor* p = config::PhysicsConfig::descriptor();
  const char* s = "SimulationParams";
  CheckSchemaRange(s, "time_step_s", p, "time_step_s", params.time_step_s);
  CheckSchemaRange(s, "rest_time_step_s", p, "rest_time_step_s", params.rest_time_step_s);
  CheckRange(s, "rest_time_step_s", params.rest_time_step_s, params.time_step_s, 1e9);
  CheckSchemaRange(s, "max_sim_time_s", p, "max_sim_time_s", params.max_sim_time_s);
  CheckSchemaRange(s, "settle_translation_mm", p, "settle_translation_mm",
                   params.settle_translation_mm);
  CheckSchemaRange(s, "settle_rotation_deg", p, "settle_rotation_deg", params.settle_rotation_deg);
  CheckSchemaRange(s, "settle_window_s", p, "settle_window_s", params.settle_window_s);
  CheckRange(s, "settle_window_s", params.settle_window_s, params.time_step_s,
             params.max_sim_time_s);
  CheckSchemaRange(s, "drop_height_mm", p, "drop_height_mm", params.drop_height_mm);
  CheckSchemaRange(s, "solver_iterations", p, "solver_iterations", params.solver_iterations);
  CheckRange("SimulationParams", "drop_point_mm.x", params.drop_point_mm.x(),
             -bin.inner_length_mm / 2, bin.inner_length_mm / 2);
  CheckRange("SimulationParams", "drop_point_mm.y", params.drop_point_mm.y(),
             -bin.inner_width_mm / 2, bin.inner_width_mm / 2);
}

}  // namespace pile_internal
}  // namespace stackgen
