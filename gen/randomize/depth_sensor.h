#pragma once

// A 3D camera's depth made from the exact one: what a structured-light or active stereo camera
// beside the colour camera would measure, with its holes and errors (config Sensor3dConfig).
//
// The renderer gives the exact depth, the depth seen from the projector and, per pixel, how much
// of the projected pattern comes back (Renderer's projector_return); these functions turn them
// into the sensor's depth: ProjectorVisible finds the projector's shadow, SensorDepth the rest.
// Pure functions of their inputs and the engine's draws.

#include <cstdint>
#include <random>

#include <opencv2/core.hpp>

#include "gen/render/renderer.h"
#include "stackgen_config.pb.h"

namespace stackgen {

/// What one 3D camera does to depth (every field as in Sensor3dConfig, after its preset).
struct DepthSensorModel {
  double baseline_mm = 120;  // the projector's offset along the camera's x axis, not 0
  double noise_at_1m_mm = 0.2;  // std of the depth error at 1 m; x (z / 1 m)^2 at z, >= 0
  double min_return = 0.02;  // below: no depth (1 = a white matte surface facing the projector)
  double max_return = 20;    // above: saturated, no depth
  double edge_step_mm = 5;   // a larger step to a neighbour makes a candidate flying pixel, > 0
  double flying_pixel_probability = 0.3;  // 0..1
  double quantization_mm = 0.1;           // depth rounded to multiples of this; 0: not
  int subsample = 1;                      // one measurement per subsample x subsample pixels
};

/// The model of a validated config (gen/config: presets applied).
DepthSensorModel DepthSensorOf(const config::Sensor3dConfig& config);

/// The projector's (or the second camera's) view, for its depth image: the camera moved
/// baseline_mm along its own x axis, same orientation and image size, its focal lengths scaled
/// down and its principal point moved so that its image holds every point the camera sees at
/// nearest_mm or farther (the scene's nearest depth), one pixel to spare. Throws
/// std::invalid_argument for a baseline of 0, or a baseline or nearest_mm not finite or
/// nearest_mm not positive.
CameraModel ProjectorCamera(const CameraModel& camera, double baseline_mm, double nearest_mm);

/// CV_8UC1, 255 where the surface at the pixel's centre is lit by the projector: it has depth
/// (depth_mm CV_32FC1 > 0, camera z in mm, the camera's intrinsics `camera`) and its point, seen
/// from the projector at `baseline_mm` along the camera's x axis (intrinsics `projector`, the
/// same orientation), lands inside the projector's image and is not behind what the projector
/// sees there: at least one of the four projector pixels around it has a depth
/// (projector_depth_mm, CV_32FC1, projector z in mm, 0 = nothing) no nearer than the point's
/// own projector z less max(0.5 mm, 0.2 % of it). 0 elsewhere: the projector's shadow, and
/// where there is no depth. Throws std::invalid_argument for images of the wrong type or size.
cv::Mat ProjectorVisible(const cv::Mat& depth_mm, const Intrinsics& camera,
                         const cv::Mat& projector_depth_mm, const Intrinsics& projector,
                         double baseline_mm);

/// The depth the 3D camera reports, CV_32FC1 mm, 0 = no depth, from the exact depth (`ideal_mm`,
/// CV_32FC1, 0 = nothing), where the projector lights it (`visible`, CV_8UC1 from
/// ProjectorVisible) and the pattern's return (`projector_return`, CV_32FC1), in this order:
///  1. no depth where the exact one is 0, the projector does not light it, or the return is
///     below model.min_return or above model.max_return;
///  2. flying pixels: a measured pixel whose exact depth differs from that of one of its four
///     neighbours (with depth) by more than edge_step_mm is, with probability
///     flying_pixel_probability, moved to a depth drawn uniformly between its own and that
///     neighbour's (the neighbour of the largest step);
///  3. axial noise: Gaussian, std noise_at_1m_mm x (z / 1000 mm)^2;
///  4. lateral resolution: each subsample x subsample block takes its centre pixel's value;
///  5. rounded to multiples of quantization_mm (when > 0).
/// The engine's draws: per candidate flying pixel (row by row) one for the chance and, when it
/// flies, one for the depth; then two per pair of measured pixels for the noise (row by row,
/// Box-Muller), only when noise_at_1m_mm > 0. Throws std::invalid_argument for images of the
/// wrong type or size.
cv::Mat SensorDepth(const cv::Mat& ideal_mm, const cv::Mat& visible,
                    const cv::Mat& projector_return, const DepthSensorModel& model,
                    std::mt19937_64& engine);

}  // namespace stackgen
