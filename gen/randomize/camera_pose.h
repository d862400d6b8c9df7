#pragma once

#include <random>

#include <Eigen/Geometry>

#include "gen/render/camera.h"
#include "stackgen_config.pb.h"

namespace stackgen {

/// The nominal pose, world from camera, mm: the camera at `distance_mm` above the bin floor
/// centre (the world origin, z up), looking straight down, image x along world +x, image y along
/// world -y (OpenCV camera frame). Equals WorldFromCamera (gen/config) for distance =
/// camera.height_mm.
Eigen::Isometry3d NominalWorldFromCamera(double distance_mm);

/// A camera pose around the nominal one, world from camera, mm. Takes exactly four values from
/// `engine`, in this order and whatever the ranges, so switching one range on never shifts the
/// others' draws:
///  - distance d of the camera centre from the floor centre, uniform in
///    [height_mm - distance_jitter_mm, height_mm + distance_jitter_mm];
///  - tilt t of the optical axis from straight down, the angle uniform in [0, tilt_max_deg]
///    (uniform in angle, not in solid angle: small tilts are as likely as large ones);
///  - azimuth a of the tilt, uniform in [0, 360) degrees from world +x towards +y: the camera
///    centre lies at d (sin t cos a, sin t sin a, cos t), on the sphere of radius d about the
///    floor centre, and the optical axis still passes through the floor centre (the nominal pose
///    turned by t about the horizontal axis through the origin perpendicular to the azimuth);
///  - roll r, uniform in [-roll_max_deg, roll_max_deg], turning the camera by r about its own
///    optical axis (+z); with no tilt, the camera x axis then points along world
///    (cos r, -sin r, 0).
/// With all three ranges zero the result equals NominalWorldFromCamera(height_mm) exactly.
Eigen::Isometry3d SampleWorldFromCamera(const config::CameraConfig& camera,
                                        std::mt19937_64& engine);

/// True when the 8 corners of the bin interior (x = +-inner_length/2, y = +-inner_width/2,
/// z = 0 and z = inner_height, mm) all lie in front of the camera (z > 0 in the camera frame) and
/// project inside the image, [0, width - 1] x [0, height - 1].
bool BinInView(const Intrinsics& intrinsics, const Eigen::Isometry3d& world_from_camera,
               const config::BinConfig& bin);

/// SampleWorldFromCamera; when camera.require_bin_in_view, drawn again (from the same engine)
/// until BinInView, at most 100 times. Throws std::runtime_error when the nominal pose itself
/// does not see the bin (naming camera.height_mm), or when 100 draws in a row leave the bin out
/// of view: the message gives camera.distance_jitter_mm, tilt_max_deg and roll_max_deg with their
/// values and says which of them to lower (those that lose the bin on their own at their
/// extremes).
Eigen::Isometry3d SampleCameraPose(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                                   const config::BinConfig& bin, std::mt19937_64& engine);

/// The fraction of `draws` poses from SampleWorldFromCamera (with a fixed engine, so the same
/// config always gives the same estimate) for which BinInView holds.
double BinInViewRate(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                     const config::BinConfig& bin, int draws);

/// Refuses, before a run, camera ranges that would make SampleCameraPose give up now and then:
/// when camera.require_bin_in_view and fewer than 20 % of 2000 drawn poses see the whole bin,
/// throws std::runtime_error with that rate and which range to lower (as SampleCameraPose).
void CheckCameraPoseRanges(const config::CameraConfig& camera, const Intrinsics& intrinsics,
                           const config::BinConfig& bin);

}  // namespace stackgen
