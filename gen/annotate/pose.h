#pragma once

#include <Eigen/Geometry>
#include <stackgen/pose.hpp>

namespace stackgen {

/// The message form of a rigid transform target_from_source whose translation is in millimetres:
/// translation_mm, the rotation as a row-major 3x3 matrix and as a unit quaternion (w, x, y, z)
/// with w >= 0 (w == 0: the first nonzero of x, y, z is positive). Throws nothing.
stackgen::pose ToPoseMessage(const Eigen::Isometry3d& target_from_source);

/// The rigid transform (millimetres) of a pose message, from translation_mm and the row-major
/// rotation (the quaternion is not read). Throws std::runtime_error naming the field if a value
/// is not finite or the rotation is not orthonormal with determinant +1 (tolerance 1e-6).
Eigen::Isometry3d FromPoseMessage(const stackgen::pose& pose);

/// The posture angles (alpha, beta, gamma) in degrees of a rotation world_R_object written as
/// Rz(alpha) * Ry(beta) * Rx(gamma) about the world Z, Y, X axes: alpha and gamma in
/// (-180, 180], beta in [-90, 90]. At gimbal lock (beta = +-90) all of the rotation about the
/// vertical goes into alpha and gamma is 0. `world_R_object` must be a rotation matrix; throws
/// nothing.
Eigen::Vector3d PostureAnglesDeg(const Eigen::Matrix3d& world_R_object);

/// The rotation Rz(alpha) * Ry(beta) * Rx(gamma) of posture angles (alpha, beta, gamma) in
/// degrees. Throws nothing.
Eigen::Matrix3d RotationFromPostureDeg(const Eigen::Vector3d& alpha_beta_gamma_deg);

}  // namespace stackgen
