#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace stackgen {

/// The light arriving from every direction around a scene: linear RGB radiance (1 = a white
/// diffuse surface lit by it from all sides shows white before tone mapping) as an
/// equirectangular image with the world's z axis up. Row 0 is the zenith (+z), the last row the
/// nadir; column u (of W) looks towards azimuth phi = 2 pi (u + 0.5) / W - pi, measured from +x
/// towards +y. See DirectionOfPixel.
struct EnvironmentMap {
  cv::Mat radiance;  // CV_32FC3, linear RGB, width = 2 x height
  std::string name;  // the file, or "hall <variant>" for a procedural one
};

/// The unit direction (world, z up) of the centre of pixel (u, v) of a width x height
/// equirectangular image, and back: the continuous pixel coordinates (centres at integers) of a
/// direction.
Eigen::Vector3d DirectionOfPixel(double u, double v, int width, int height);
Eigen::Vector2d PixelOfDirection(const Eigen::Vector3d& direction, int width, int height);

/// Reads a Radiance `.hdr` (OpenCV) or OpenEXR `.exr` (libOpenEXR) equirectangular image as
/// linear radiance, resampled to a 2:1 image when it is not one. Throws std::runtime_error
/// naming the file when it cannot be read, is not an image of positive size, or holds a
/// negative or non-finite value.
EnvironmentMap LoadEnvironment(const std::string& path);

/// The environment files of a folder: every `.hdr` and `.exr` file in it, sorted by name.
/// Throws std::runtime_error naming the folder when it is missing or holds none.
std::vector<std::string> ListEnvironmentFiles(const std::string& folder);

/// A procedural industrial hall, `height` x 2 height pixels: a dark ceiling with rows of
/// bright light strips (the parts' highlights), walls with windows and a darker band below,
/// a grey floor. The layout (strip count and spacing, room size, colours, brightness) is a pure
/// function of `variant`. Mean radiance about 0.3..0.6, the strips 8..25. Throws
/// std::invalid_argument for height < 8.
EnvironmentMap MakeHallEnvironment(uint64_t variant, int height = 256);

/// An environment made ready for shading: specular radiance prefiltered by roughness and the
/// irradiance as spherical harmonics.
struct PrefilteredEnvironment {
  /// Level k (k = 0 .. n-1, n = kLevels) is (W >> k) x (H >> k), CV_32FC3: the radiance
  /// reflected by a GGX lobe of roughness k / (n - 1) around each direction (split sum, with
  /// n = v = r), by filtered importance sampling. Level 0 is the radiance itself.
  std::vector<cv::Mat> levels;
  /// Irradiance divided by pi (so a white Lambertian surface with normal n shows
  /// sum_i coefficients[i] Y_i(n)) as 9 spherical-harmonic coefficients (bands 0..2, the
  /// cosine lobe applied), in the order Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22.
  std::array<Eigen::Vector3f, 9> irradiance_sh;
  std::string name;
  static constexpr int kLevels = 6;
};

/// Prefilters `environment` (resampled to base_width x base_width / 2 first, area-averaged) for
/// the split-sum approximation. Deterministic (Hammersley points). Throws std::invalid_argument
/// for an empty map or a base_width not a multiple of 2^kLevels.
PrefilteredEnvironment Prefilter(const EnvironmentMap& environment, int base_width = 256);

/// The octahedral map (Engelhardt and Dachsbacher 2008) of an equirectangular CV_32FC3 image,
/// size x size, bilinearly resampled: direction d lands at p = d / (|dx| + |dy| + |dz|), its xy
/// folded over the diagonals when dz < 0 ((1 - |py|, 1 - |px|) with the signs of px, py), at
/// texture coordinates p * 0.5 + 0.5 (column from x, row from y). The shader finds a direction's
/// texel with a few additions instead of the equirectangular map's atan and acos.
cv::Mat OctahedralOf(const cv::Mat& equirectangular, int size);

/// The unit direction of texture coordinates (s, t) in [0, 1]^2 of an octahedral map.
Eigen::Vector3d DirectionOfOctahedral(double s, double t);

/// A white Lambertian surface's radiance for normal `n` (world, unit) from spherical harmonics.
Eigen::Vector3f EvaluateIrradianceSh(const std::array<Eigen::Vector3f, 9>& sh,
                                     const Eigen::Vector3d& n);

/// The split-sum BRDF lookup table (Karis 2013) for GGX with Smith height-correlated visibility
/// and Schlick's Fresnel: size x size CV_32FC2, column i for n.v = (i + 0.5) / size, row j for
/// perceptual roughness (j + 0.5) / size. Channel 0 is the directional albedo's part that does
/// not scale with f0 (the Fresnel peak), channel 1 the whole albedo for f0 = 1, so the
/// reflectance for f0 is mix(c0, c1, f0) (Filament's DFG). Deterministic.
cv::Mat ComputeDfgLut(int size = 32, int samples = 512);

}  // namespace stackgen
