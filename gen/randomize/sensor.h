#pragma once

#include <cstdint>
#include <random>

#include <opencv2/core.hpp>

#include "stackgen_config.pb.h"

namespace stackgen {

/// The sensor effects of one scene (drawn by SampleSensorEffects). The defaults are the
/// identity: an image they are applied to stays bit-identical.
struct SensorEffects {
  double gaussian_sigma = 0;        // std of additive Gaussian noise, gray levels (0..255), >= 0
  double salt_pepper_fraction = 0;  // fraction of pixels set to black or white, 0..1
  double blur_sigma_px = 0;         // Gaussian blur sigma, pixels; < 0.3: no blur
  double brightness = 0;            // offset, fraction of full scale (0.1 adds 25.5 levels)
  double contrast = 1;              // gain about mid-gray (127.5), > 0
  double gamma = 1;                 // out = in^gamma on [0, 1]: > 1 darkens, < 1 brightens
  uint64_t noise_seed = 0;          // seeds the per-pixel noise
};

/// Draws every parameter from `engine`, always exactly seven values in this order: gaussian_sigma
/// uniform in [0, gaussian_sigma_max], salt_pepper_fraction in [0, salt_pepper_max],
/// blur_sigma_px in [0, blur_sigma_max_px], brightness in [-brightness_max, brightness_max],
/// contrast in [1 - contrast_max, 1 + contrast_max], gamma log-uniform in
/// [1 / (1 + gamma_max), 1 + gamma_max], then noise_seed (one raw engine value). With
/// config.enabled() false it returns the identity effects (SensorEffects{}) after still making
/// the same draws.
SensorEffects SampleSensorEffects(const config::SensorConfig& config, std::mt19937_64& engine);

/// Applies `effects` to an 8-bit image in place (CV_8UC1, or CV_8UC3 of any channel order), in
/// camera order, every step saturating to 0..255:
///  1. blur (optics): Gaussian, sigma blur_sigma_px, when it is >= 0.3 (borders reflected);
///  2. response: v = 255 (v / 255)^gamma, then v = (v - 127.5) contrast + 127.5, then
///     v += 255 brightness, rounded once through one lookup table;
///  3. Gaussian noise of std gaussian_sigma, independent per pixel and channel, rounded;
///  4. salt and pepper: round(salt_pepper_fraction x pixels) pixels drawn with replacement
///     (so slightly fewer distinct ones) set to black or white in every channel, half each.
/// The per-pixel noise comes from SplitMix64 streams seeded from noise_seed (one per block of
/// rows, so the result is the same whatever the number of threads): the same effects on the same
/// image give the same bytes on every run. Identity steps are skipped, so identity effects leave
/// the image bit-identical. Throws std::runtime_error when `image` is null, empty or of another
/// type, or an effect is out of range (negative sigma, fraction outside [0, 1], contrast or
/// gamma not positive).
void ApplySensorEffects(const SensorEffects& effects, cv::Mat* image);

}  // namespace stackgen
