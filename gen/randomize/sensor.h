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
  // physically based frames only (DevelopLinearImage):
  double exposure_ev = 0;  // radiance x 2^exposure_ev before the tone curve
  double shot_noise = 0;   // photon noise: variance shot_noise x signal (exposed linear units)
  double read_noise = 0;   // read-out noise: std in exposed linear units (1 = white)
  double white_balance[3] = {1, 1, 1};  // gains of linear R, G, B (a white balance a little off)
  bool clipped_tone = false;  // sRGB clipped at white instead of the filmic (ACES) tone curve
  double saturation = 1;  // linear RGB about its Rec. 709 luminance: 0 grey, 1 as rendered, >= 0
};

/// Draws every parameter from `engine`, always the same values in this order: gaussian_sigma
/// uniform in [0, gaussian_sigma_max], salt_pepper_fraction in [0, salt_pepper_max],
/// blur_sigma_px in [0, blur_sigma_max_px], brightness in [-brightness_max, brightness_max],
/// contrast in [1 - contrast_max, 1 + contrast_max], gamma log-uniform in
/// [1 / (1 + gamma_max), 1 + gamma_max], noise_seed (one raw engine value), then exposure_ev
/// uniform in [exposure_ev_min, exposure_ev_max], shot_noise in [0, shot_noise_max] and
/// read_noise in [0, read_noise_max] (the first seven draws are what they always were), then
/// three white-balance gains, each uniform in [1 - white_balance_max, 1 + white_balance_max],
/// whether the tone is clipped (chance clipped_tone_probability) and the saturation, uniform in
/// [saturation_min, saturation_max]: fifteen draws. With config.enabled() false it returns the
/// identity effects (SensorEffects{}) after still making the same draws.
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

/// A physically based frame through the camera: linear RGB radiance (CV_32FC3, 1 = white) to an
/// 8-bit image, CV_8UC3 RGB or, when `gray`, CV_8UC1, in camera order:
///  1. blur (optics) in linear light, as in ApplySensorEffects;
///  2. gray: luminance Y = 0.2126 R + 0.7152 G + 0.0722 B (Rec. 709 primaries), when `gray`;
///  3. white balance and saturation (colour only): x white_balance per channel, then each pixel
///     moved toward its luminance Y (Rec. 709), c' = Y + saturation (c - Y); exposure:
///     x 2^exposure_ev;
///  4. AddLinearNoise: shot and read noise where the sensor makes them, before the tone curve;
///  5. the filmic tone curve (ACES, Narkowicz's 2015 fit) and sRGB encoding, rounded to 8 bits
///     (through a table indexed by the square root of the signal, within half a level);
///  6. the response table (gamma, contrast, brightness) and salt and pepper, as
///     ApplySensorEffects; gaussian_sigma is not used (read_noise takes its place).
/// Deterministic as ApplySensorEffects. Throws std::runtime_error for an empty image or another
/// type, or effects out of range (as ApplySensorEffects, or a negative or non-finite exposure,
/// shot or read noise, or a negative or non-finite saturation).
cv::Mat DevelopLinearImage(const SensorEffects& effects, const cv::Mat& linear_rgb, bool gray);

/// Step 4 of DevelopLinearImage on a linear image (CV_32FC1 or CV_32FC3) in place: adds to each
/// value s an independent Gaussian draw of variance shot_noise x max(s, 0) + read_noise^2
/// (Poisson photon noise in its Gaussian limit, plus read noise), from SplitMix64 streams seeded
/// from noise_seed (one per block of rows).
void AddLinearNoise(const SensorEffects& effects, cv::Mat* linear);

/// The ACES filmic tone curve (Narkowicz 2015), linear scene value to display-linear 0..1.
double AcesFilmic(double x);

}  // namespace stackgen
