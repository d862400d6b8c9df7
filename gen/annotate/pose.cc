#include "gen/annotate/pose.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace stackgen {
namespace {

// below this cos(beta) the rotation is taken as gimbal-locked (beta = +-90 degrees)
constexpr double kGimbalLockCosBeta = 1e-10;
// tolerance on R^T R = I and det R = 1 when reading a pose message
constexpr double kRotationTolerance = 1e-6;

double RadToDeg(double rad) { return rad * 180.0 / M_PI; }
double DegToRad(double deg) { return deg * M_PI / 180.0; }

// an angle from atan2 in degrees, mapped from [-180, 180] to (-180, 180]
double WrapDeg(double rad) {
  const double deg = RadToDeg(rad);
  return deg <= -180.0 ? deg + 360.0 : deg;
}

}  // namespace

stackgen::pose ToPoseMessage(const Eigen::Isometry3d& target_from_source) {
  stackgen::pose message{};
  const Eigen::Matrix3d rotation = target_from_source.linear();
  const Eigen::Vector3d translation = target_from_source.translation();
  // translation and the row-major rotation
  for (int i = 0; i < 3; ++i) message.translation_mm[i] = translation[i];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) message.rotation[3 * r + c] = rotation(r, c);
  }
  // the unit quaternion on the w >= 0 half (ties at w == 0 broken by the first nonzero of x,y,z)
  Eigen::Quaterniond q(rotation);
  q.normalize();
  double wxyz[4] = {q.w(), q.x(), q.y(), q.z()};
  int sign = 1;
  for (const double v : wxyz) {
    if (v != 0.0) {
      sign = v < 0.0 ? -1 : 1;
      break;
    }
  }
  for (int i = 0; i < 4; ++i) message.quaternion_wxyz[i] = sign * wxyz[i] + 0.0;
  return message;
}

Eigen::Isometry3d FromPoseMessage(const stackgen::pose& pose) {
  // every value must be a number
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(pose.translation_mm[i])) {
      throw std::runtime_error("pose.translation_mm[" + std::to_string(i) + "] is not finite");
    }
  }
  Eigen::Matrix3d rotation;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const double v = pose.rotation[3 * r + c];
      if (!std::isfinite(v)) {
        throw std::runtime_error("pose.rotation[" + std::to_string(3 * r + c) + "] is not finite");
      }
      rotation(r, c) = v;
    }
  }
  // the rotation must be a proper rotation
  const double orthogonality_error =
      (rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double determinant = rotation.determinant();
  if (orthogonality_error > kRotationTolerance ||
      std::abs(determinant - 1.0) > kRotationTolerance) {
    throw std::runtime_error("pose.rotation is not a rotation matrix (|R^T R - I| = " +
                             std::to_string(orthogonality_error) +
                             ", det = " + std::to_string(determinant) + ")");
  }
  Eigen::Isometry3d target_from_source = Eigen::Isometry3d::Identity();
  target_from_source.linear() = rotation;
  target_from_source.translation() =
      Eigen::Vector3d(pose.translation_mm[0], pose.translation_mm[1], pose.translation_mm[2]);
  return target_from_source;
}

Eigen::Vector3d PostureAnglesDeg(const Eigen::Matrix3d& world_R_object) {
  const Eigen::Matrix3d& r = world_R_object;
  // R = Rz(a) Ry(b) Rx(g): first column (cos a cos b, sin a cos b, -sin b)
  const double cos_beta = std::hypot(r(0, 0), r(1, 0));
  const double beta = std::atan2(-r(2, 0), cos_beta);
  if (cos_beta < kGimbalLockCosBeta) {
    // gimbal lock: Rx(g) and Rz(a) turn about the same axis; put it all in alpha, gamma = 0.
    // for both signs of beta the second column is (-sin a, cos a, 0)
    const double alpha = std::atan2(-r(0, 1), r(1, 1));
    return {WrapDeg(alpha), r(2, 0) < 0.0 ? 90.0 : -90.0, 0.0};
  }
  const double alpha = std::atan2(r(1, 0), r(0, 0));
  // gamma from Rz(-a) R = Ry(b) Rx(g), whose second row is (0, cos g, -sin g): stays accurate
  // when cos(beta) is small
  const double sa = std::sin(alpha), ca = std::cos(alpha);
  const double gamma = std::atan2(sa * r(0, 2) - ca * r(1, 2), ca * r(1, 1) - sa * r(0, 1));
  return {WrapDeg(alpha), RadToDeg(beta), WrapDeg(gamma)};
}

Eigen::Matrix3d RotationFromPostureDeg(const Eigen::Vector3d& alpha_beta_gamma_deg) {
  const Eigen::Vector3d& a = alpha_beta_gamma_deg;
  return (Eigen::AngleAxisd(DegToRad(a[0]), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(DegToRad(a[1]), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(DegToRad(a[2]), Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

}  // namespace stackgen
