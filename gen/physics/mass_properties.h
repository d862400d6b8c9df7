#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "gen/mesh/mesh.h"

namespace stackgen {

/// Mass properties of a closed, outward-wound triangle mesh of uniform density.
struct MassProperties {
  double volume_mm3 = 0;
  double mass_kg = 0;
  /// Centre of mass in the mesh (object) frame, millimetres.
  Eigen::Vector3d center_of_mass_mm = Eigen::Vector3d::Zero();
  /// Inertia tensor about the centre of mass, axes of the object frame, kg mm^2.
  Eigen::Matrix3d inertia_kg_mm2 = Eigen::Matrix3d::Zero();
  /// Principal moments of inertia (ascending), kg mm^2, about the axes of principal_from_object.
  Eigen::Vector3d principal_moments_kg_mm2 = Eigen::Vector3d::Zero();
  /// The object frame seen from the principal frame (origin at the centre of mass, axes along the
  /// principal axes of inertia, right-handed); millimetres.
  Eigen::Isometry3d principal_from_object = Eigen::Isometry3d::Identity();
};

/// Volume, mass, centre of mass and inertia of `mesh` (millimetres) at `density_kg_m3`, by
/// summing signed tetrahedra, so the mesh must be closed and wound counter-clockwise seen from
/// outside. Throws std::runtime_error if the enclosed volume is not positive or the density is not
/// positive; `what` names the mesh in the message.
MassProperties ComputeMassProperties(const TriangleMesh& mesh, double density_kg_m3,
                                     const std::string& what);

}  // namespace stackgen
