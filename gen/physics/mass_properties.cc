#include "gen/physics/mass_properties.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include <Eigen/Eigenvalues>

namespace stackgen {

MassProperties ComputeMassProperties(const TriangleMesh& mesh, double density_kg_m3,
                                     const std::string& what) {
  if (!(density_kg_m3 > 0) || !std::isfinite(density_kg_m3)) {
    std::ostringstream message;
    message << what << ": density_kg_m3 must be > 0, got " << density_kg_m3;
    throw std::runtime_error(message.str());
  }

  // integrate over the tetrahedra (origin, a, b, c): volume, first and second moments
  double volume = 0;
  Eigen::Vector3d first_moment = Eigen::Vector3d::Zero();
  Eigen::Matrix3d second_moment = Eigen::Matrix3d::Zero();  // integral of x x^T dV
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.positions_mm.at(t[0]).cast<double>();
    const Eigen::Vector3d b = mesh.positions_mm.at(t[1]).cast<double>();
    const Eigen::Vector3d c = mesh.positions_mm.at(t[2]).cast<double>();
    const double det = a.dot(b.cross(c));
    const Eigen::Vector3d sum = a + b + c;
    volume += det / 6.0;
    first_moment += det / 24.0 * sum;
    second_moment +=
        det / 120.0 *
        (a * a.transpose() + b * b.transpose() + c * c.transpose() + sum * sum.transpose());
  }
  if (!(volume > 0) || !std::isfinite(volume)) {
    std::ostringstream message;
    message << what << ": the mesh encloses no positive volume (" << volume
            << " mm^3); it must be closed and wound counter-clockwise seen from outside";
    throw std::runtime_error(message.str());
  }

  // mass, centre of mass, and the inertia about it
  MassProperties result;
  const double density_kg_mm3 = density_kg_m3 * 1e-9;
  result.volume_mm3 = volume;
  result.mass_kg = density_kg_mm3 * volume;
  result.center_of_mass_mm = first_moment / volume;
  const Eigen::Vector3d& com = result.center_of_mass_mm;
  const Eigen::Matrix3d central = second_moment - volume * com * com.transpose();
  result.inertia_kg_mm2 =
      density_kg_mm3 * (central.trace() * Eigen::Matrix3d::Identity() - central);

  // principal axes, as a right-handed rotation
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(result.inertia_kg_mm2);
  Eigen::Matrix3d object_from_principal_rotation = solver.eigenvectors();
  if (object_from_principal_rotation.determinant() < 0) {
    object_from_principal_rotation.col(2) *= -1;
  }
  result.principal_moments_kg_mm2 = solver.eigenvalues();
  Eigen::Isometry3d object_from_principal = Eigen::Isometry3d::Identity();
  object_from_principal.linear() = object_from_principal_rotation;
  object_from_principal.translation() = com;
  result.principal_from_object = object_from_principal.inverse();
  return result;
}

}  // namespace stackgen
