#include "gen/randomize/camera_pose.h"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "gen/config/config.h"
#include "gen/randomize/uniform.h"

namespace stackgen {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRadPerDeg = kPi / 180.0;
constexpr int kMaxPoseDraws = 100;
// CheckCameraPoseRanges refuses ranges whose poses see the bin less often than this: at 20 %, 100
// failed draws in a row (SampleCameraPose gives up) happen once in 5e9 scenes
constexpr double kMinInViewRate = 0.2;

// the nominal pose at `distance_mm`, tilted by `tilt_rad` towards `azimuth_rad` about the floor
// centre, then rolled by `roll_rad` about its optical axis.
Eigen::Isometry3d PoseAround(double distance_mm, double tilt_rad, double azimuth_rad,
                             double roll_rad) {
  const Eigen::Isometry3d nominal = NominalWorldFromCamera(distance_mm);
  // tilt: turning about a horizontal axis through the floor centre keeps the axis aimed at it;
  // the axis (-sin a, cos a, 0) moves the camera centre towards (cos a, sin a, 0).
  const Eigen::Vector3d tilt_axis(-std::sin(azimuth_rad), std::cos(azimuth_rad), 0.0);
  const Eigen::Matrix3d world_tilt = Eigen::AngleAxisd(tilt_rad, tilt_axis).toRotationMatrix();
  // roll: about the camera's own z axis, so it acts on the right.
  const Eigen::Matrix3d camera_roll =
      Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = world_tilt * nominal.linear() * camera_roll;
  pose.translation() = world_tilt * nominal.translation();
  return pose;
}

// the names of the ranges that lose the bin on their own, at their extremes.
std::vector<std::string> RangesLosingTheBin(const config::CameraConfig& camera,
                                            const Intrinsics& intrinsics,
                                            const config::BinConfig& bin) {
  std::vector<std::string> culprits;
  const double height = camera.height_mm();
  // distance: the closest camera sees the least.
  if (!BinInView(intrinsics, PoseAround(height - camera.distance_jitter_mm(), 0, 0, 0), bin)) {
    culprits.push_back("camera.distance_jitter_mm");
  }
  // tilt: the largest tilt, towards several directions.
  const double tilt = camera.tilt_max_deg() * kRadPerDeg;
  for (int i = 0; i < 16; ++i) {
    if (!BinInView(intrinsics, PoseAround(height, tilt, i * kPi / 8, 0), bin)) {
      culprits.push_back("camera.tilt_max_deg");
      break;
    }
  }
  // roll: the worst roll of a rectangle may lie inside the range, so try across it.
  const double roll = camera.roll_max_deg() * kRadPerDeg;
  for (int i = 0; i <= 32; ++i) {
    if (!BinInView(intrinsics, PoseAround(height, 0, 0, roll * (i / 16.0 - 1.0)), bin)) {
      culprits.push_back("camera.roll_max_deg");
      break;
    }
  }
  return culprits;
}

// why poses lose the bin: the nominal pose, or the ranges that lose it on their own; `lead`
// says what happened.
std::string OutOfViewMessage(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                             const config::BinConfig& bin, const std::string& lead) {
  std::ostringstream message;
  message << "camera: " << lead << " (camera.require_bin_in_view is true): ";
  if (!BinInView(intrinsics, PoseAround(camera.height_mm(), 0, 0, 0), bin)) {
    message << "even the nominal pose (camera.height_mm = " << camera.height_mm()
            << ", looking straight down) does not see the whole bin; raise camera.height_mm, "
               "shorten the focal length or make the bin smaller";
    return message.str();
  }
  message << "camera.distance_jitter_mm = " << camera.distance_jitter_mm()
          << ", camera.tilt_max_deg = " << camera.tilt_max_deg()
          << ", camera.roll_max_deg = " << camera.roll_max_deg()
          << " leave the bin out of view too often; lower ";
  const std::vector<std::string> culprits = RangesLosingTheBin(camera, intrinsics, bin);
  if (culprits.empty()) {
    message << "them (together they lose the bin), or raise camera.height_mm";
  } else {
    for (size_t i = 0; i < culprits.size(); ++i) {
      message << (i == 0 ? "" : i + 1 == culprits.size() ? " and " : ", ") << culprits[i];
    }
    message << (culprits.size() == 1 ? " (it loses" : " (each loses")
            << " the bin on its own at its extreme), or raise camera.height_mm";
  }
  return message.str();
}

}  // namespace

Eigen::Isometry3d NominalWorldFromCamera(double distance_mm) {
  // the config's nominal pose, at this distance
  config::CameraConfig camera;
  camera.set_height_mm(distance_mm);
  return WorldFromCamera(camera);
}

Eigen::Isometry3d SampleWorldFromCamera(const config::CameraConfig& camera,
                                        std::mt19937_64& engine) {
  // always four draws, in a fixed order, whatever the ranges.
  const double jitter = camera.distance_jitter_mm();
  const double distance = camera.height_mm() + Uniform(engine, -jitter, jitter);
  const double tilt = Uniform(engine, 0.0, camera.tilt_max_deg()) * kRadPerDeg;
  const double azimuth = Uniform(engine, 0.0, 2.0 * kPi);
  const double roll_max = camera.roll_max_deg();
  const double roll = Uniform(engine, -roll_max, roll_max) * kRadPerDeg;
  return PoseAround(distance, tilt, azimuth, roll);
}

bool BinInView(const Intrinsics& intrinsics, const Eigen::Isometry3d& world_from_camera,
               const config::BinConfig& bin) {
  const Eigen::Isometry3d camera_from_world = world_from_camera.inverse();
  const double half_length = bin.inner_length_mm() / 2;
  const double half_width = bin.inner_width_mm() / 2;
  for (const double z : {0.0, bin.inner_height_mm()}) {
    for (const double y : {-half_width, half_width}) {
      for (const double x : {-half_length, half_length}) {
        const Eigen::Vector3d corner = camera_from_world * Eigen::Vector3d(x, y, z);
        // behind the camera (or on its plane): not seen.
        if (!(corner.z() > 0)) return false;
        const double u = intrinsics.fx * corner.x() / corner.z() + intrinsics.cx;
        const double v = intrinsics.fy * corner.y() / corner.z() + intrinsics.cy;
        if (!(u >= 0 && u <= intrinsics.width - 1 && v >= 0 && v <= intrinsics.height - 1)) {
          return false;
        }
      }
    }
  }
  return true;
}

Eigen::Isometry3d SampleCameraPose(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                                   const config::BinConfig& bin, std::mt19937_64& engine) {
  if (!camera.require_bin_in_view()) return SampleWorldFromCamera(camera, engine);
  // redraw until the whole bin interior is in the image.
  for (int draw = 0; draw < kMaxPoseDraws; ++draw) {
    const Eigen::Isometry3d world_from_camera = SampleWorldFromCamera(camera, engine);
    if (BinInView(intrinsics, world_from_camera, bin)) return world_from_camera;
  }
  throw std::runtime_error(
      OutOfViewMessage(camera, intrinsics, bin,
                       std::to_string(kMaxPoseDraws) +
                           " drawn poses in a row left part of the bin interior out of the image"));
}

double BinInViewRate(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                     const config::BinConfig& bin, int draws) {
  // a fixed engine: the same config always gets the same estimate
  std::mt19937_64 engine(0x5eed);
  int seen = 0;
  for (int i = 0; i < draws; ++i) {
    seen += BinInView(intrinsics, SampleWorldFromCamera(camera, engine), bin) ? 1 : 0;
  }
  return draws > 0 ? static_cast<double>(seen) / draws : 0.0;
}

void CheckCameraPoseRanges(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                           const config::BinConfig& bin) {
  if (!camera.require_bin_in_view()) return;
  const double rate = BinInViewRate(camera, intrinsics, bin, 2000);
  if (rate >= kMinInViewRate) return;
  std::ostringstream lead;
  lead << "only " << 100 * rate << " % of the drawn poses see the whole bin interior (at least "
       << 100 * kMinInViewRate << " % needed)";
  throw std::runtime_error(OutOfViewMessage(camera, intrinsics, bin, lead.str()));
}

}  // namespace stackgen
