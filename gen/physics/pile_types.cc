#include <LinearMath/btConvexHullComputer.h>

#include <sstream>
#include <stdexcept>

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

// Throws unless lo <= value <= hi.
void CheckRange(const char* object, const char* field, double value, double lo, double hi) {
  if (!(std::isfinite(value) && value >= lo && value <= hi)) {
    std::ostringstream message;
    message << "PileSimulator: " << object << "." << field << " must be in [" << lo << ", " << hi
            << "], got " << value;
    throw std::runtime_error(message.str());
  }
}

// Builds a part type; errors start with `what`.
TypeModel MakeTypeModel(const PartType& type, const std::string& what,
                        const std::string& cache_dir) {
  const PartPhysics& physics = type.physics;
  CheckRange((what + "PartPhysics").c_str(), "density_kg_m3", physics.density_kg_m3, 1e-3, 1e6);
  CheckRange((what + "PartPhysics").c_str(), "friction", physics.friction, 0, 10);
  CheckRange((what + "PartPhysics").c_str(), "restitution", physics.restitution, 0, 1);
  CheckRange((what + "PartPhysics").c_str(), "rolling_friction_mm", physics.rolling_friction_mm, 0,
             100);
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
void CheckInputs(const BinSpec& bin, const SimulationParams& params) {
  CheckRange("BinSpec", "inner_length_mm", bin.inner_length_mm, 1e-3, 1e6);
  CheckRange("BinSpec", "inner_width_mm", bin.inner_width_mm, 1e-3, 1e6);
  CheckRange("BinSpec", "inner_height_mm", bin.inner_height_mm, 1e-3, 1e6);
  CheckRange("BinSpec", "wall_mm", bin.wall_mm, 1e-3, 1e6);
  CheckRange("BinSpec", "friction", bin.friction, 0, 10);
  CheckRange("BinSpec", "restitution", bin.restitution, 0, 1);
  CheckRange("SimulationParams", "time_step_s", params.time_step_s, 1e-4, 0.01);
  CheckRange("SimulationParams", "rest_time_step_s", params.rest_time_step_s, params.time_step_s,
             0.01);
  CheckRange("SimulationParams", "max_sim_time_s", params.max_sim_time_s, params.time_step_s, 1e5);
  CheckRange("SimulationParams", "settle_translation_mm", params.settle_translation_mm, 1e-6, 1e6);
  CheckRange("SimulationParams", "settle_rotation_deg", params.settle_rotation_deg, 1e-6, 360);
  CheckRange("SimulationParams", "settle_window_s", params.settle_window_s, params.time_step_s,
             params.max_sim_time_s);
  CheckRange("SimulationParams", "drop_height_mm", params.drop_height_mm, 0, 1e6);
  CheckRange("SimulationParams", "solver_iterations", params.solver_iterations, 5, 500);
  CheckRange("SimulationParams", "drop_point_mm.x", params.drop_point_mm.x(),
             -bin.inner_length_mm / 2, bin.inner_length_mm / 2);
  CheckRange("SimulationParams", "drop_point_mm.y", params.drop_point_mm.y(),
             -bin.inner_width_mm / 2, bin.inner_width_mm / 2);
}

}  // namespace pile_internal
}  // namespace stackgen
