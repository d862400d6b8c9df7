#pragma once

#include <opencv2/core.hpp>

#include "gen/render/camera.h"

namespace stackgen {

/// How much of the sky above each pixel's surface is open, from the depth image alone
/// (screen-space horizons, after Jimenez et al., "Practical Real-Time Strategies for Accurate
/// Indirect Occlusion", 2016): for 8 directions in the image around the pixel, the highest
/// surface within `radius_mm` of it (seen from its tangent plane; in the outer 40 % of the
/// radius the farther the less) hides the sky below that horizon; a slice's share of cosine-weighted light hidden by a
/// horizon h above the tangent plane is (1 - cos h) / 2 on each side. A flat open floor scores
/// 1, the floor at the foot of a wall taller than the radius 0.5, the bottom of a narrow crack
/// near 0. What lies outside the picture or behind what the camera sees hides nothing.
///
/// `depth_mm` is CV_32FC1 camera z (0 where nothing is drawn, which scores 1), in pixels of
/// `camera`'s intrinsics. Computed at every fourth pixel of every fourth row with a 4 x 4 pattern
/// of turned directions, averaged over that pattern between pixels of similar depth, and brought
/// back to full size from the coarse pixels at the same depth. Deterministic. Writes CV_32FC1 in [0, 1] to
/// `visibility`. Throws std::invalid_argument for another type or size, or a radius that is
/// not finite and > 0.
void EnvironmentVisibility(const cv::Mat& depth_mm, const Intrinsics& camera, double radius_mm,
                           cv::Mat* visibility);

}  // namespace stackgen
