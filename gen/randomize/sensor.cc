#include "gen/randomize/sensor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

#include <opencv2/imgproc.hpp>

#include "contract/splitmix.h"
#include "gen/randomize/uniform.h"

namespace stackgen {
namespace {

constexpr double kMinBlurSigmaPx = 0.3;
// rows per noise stream: fixed, so the noise does not depend on how rows are split on threads.
constexpr int kNoiseRowsPerStream = 16;
// the Gaussian noise table: 2^12 quantiles, five draws per 64-bit value.
constexpr int kNormalTableBits = 12;
constexpr int kNormalTableSize = 1 << kNormalTableBits;
// keeps the salt-and-pepper stream apart from the Gaussian ones.
constexpr uint64_t kSaltPepperStream = 0x5a17'9e99'e7e1'0001ULL;

// the standard normal quantile at p in (0, 1), Acklam's rational approximation (relative error
// below 1.2e-9).
double NormalQuantile(double p) {
  static constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                 -2.759285104469687e+02, 1.383577518672690e+02,
                                 -3.066479806614716e+01, 2.506628277459239e+00};
  static constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                 -1.556989798598866e+02, 6.680131188771972e+01,
                                 -1.328068155288572e+01};
  static constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                 -2.400758277161838e+00, -2.549732539343734e+00,
                                 4.374664141464968e+00,  2.938163982698783e+00};
  static constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01,
                                 2.445134137142996e+00, 3.754408661907416e+00};
  constexpr double kLow = 0.02425;
  // the tails.
  if (p < kLow || p > 1 - kLow) {
    const double q = std::sqrt(-2 * std::log(p < kLow ? p : 1 - p));
    const double x = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
                     ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1);
    return p < kLow ? x : -x;
  }
  // the central region.
  const double q = p - 0.5;
  const double r = q * q;
  return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
         (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1);
}

// equiprobable standard normal values: a uniform index into it is a (finely quantised) normal
// draw. Scaled to unit variance, so the noise std is exactly the sigma asked for.
const std::array<float, kNormalTableSize>& NormalTable() {
  static const std::array<float, kNormalTableSize> table = [] {
    std::array<double, kNormalTableSize> quantiles;
    double sum_squares = 0;
    for (int i = 0; i < kNormalTableSize; ++i) {
      quantiles[i] = NormalQuantile((i + 0.5) / kNormalTableSize);
      sum_squares += quantiles[i] * quantiles[i];
    }
    const double scale = 1 / std::sqrt(sum_squares / kNormalTableSize);
    std::array<float, kNormalTableSize> scaled;
    for (int i = 0; i < kNormalTableSize; ++i) scaled[i] = static_cast<float>(quantiles[i] * scale);
    return scaled;
  }();
  return table;
}

// gamma, contrast and brightness as one table.
cv::Mat ResponseTable(const SensorEffects& effects) {
  cv::Mat table(1, 256, CV_8U);
  for (int v = 0; v < 256; ++v) {
    double out = 255 * std::pow(v / 255.0, effects.gamma);
    out = (out - 127.5) * effects.contrast + 127.5;
    out += 255 * effects.brightness;
    table.at<uchar>(v) = cv::saturate_cast<uchar>(out);
  }
  return table;
}

void AddGaussianNoise(double sigma, uint64_t seed, cv::Mat* image) {
  // the noise values, already scaled and rounded: v + round(sigma z) is round(v + sigma z).
  const std::array<float, kNormalTableSize>& normal = NormalTable();
  std::array<int16_t, kNormalTableSize> noise;
  for (int i = 0; i < kNormalTableSize; ++i) {
    noise[i] = cv::saturate_cast<int16_t>(std::lround(sigma * normal[i]));
  }
  const int values_per_row = image->cols * image->channels();
  const int streams = (image->rows + kNoiseRowsPerStream - 1) / kNoiseRowsPerStream;
  cv::parallel_for_(cv::Range(0, streams), [&](const cv::Range& range) {
    for (int stream = range.start; stream < range.end; ++stream) {
      // one stream per block of rows, its seed mixed from the scene's noise seed.
      SplitMix64 rng(Mix64(seed + 0x632be59bd9b4e019ULL * (stream + 1)));
      const int row_end = std::min(image->rows, (stream + 1) * kNoiseRowsPerStream);
      for (int y = stream * kNoiseRowsPerStream; y < row_end; ++y) {
        uchar* row = image->ptr<uchar>(y);
        for (int i = 0; i < values_per_row;) {
          uint64_t bits = rng.Next();
          for (int k = 0; k < 64 / kNormalTableBits && i < values_per_row; ++k, ++i) {
            const int value = row[i] + noise[bits & (kNormalTableSize - 1)];
            row[i] = static_cast<uchar>(std::clamp(value, 0, 255));
            bits >>= kNormalTableBits;
          }
        }
      }
    }
  });
}

void AddSaltAndPepper(double fraction, uint64_t seed, cv::Mat* image) {
  const uint64_t pixels = image->total();
  const auto count = static_cast<uint64_t>(std::llround(fraction * static_cast<double>(pixels)));
  const int channels = image->channels();
  SplitMix64 rng(Mix64(seed ^ kSaltPepperStream));
  for (uint64_t n = 0; n < count; ++n) {
    // the high bits pick the pixel, the lowest bit black or white.
    const uint64_t bits = rng.Next();
    const auto index = static_cast<uint64_t>((static_cast<unsigned __int128>(bits) * pixels) >> 64);
    const uchar value = (bits & 1) ? 255 : 0;
    uchar* pixel =
        image->ptr<uchar>(static_cast<int>(index / image->cols)) + (index % image->cols) * channels;
    for (int c = 0; c < channels; ++c) pixel[c] = value;
  }
}

}  // namespace

SensorEffects SampleSensorEffects(const config::SensorConfig& config, std::mt19937_64& engine) {
  // always fifteen draws, in a fixed order, enabled or not.
  SensorEffects drawn;
  drawn.gaussian_sigma = Uniform(engine, 0.0, config.gaussian_sigma_max());
  drawn.salt_pepper_fraction = Uniform(engine, 0.0, config.salt_pepper_max());
  drawn.blur_sigma_px = Uniform(engine, 0.0, config.blur_sigma_max_px());
  drawn.brightness = Uniform(engine, -config.brightness_max(), config.brightness_max());
  drawn.contrast = Uniform(engine, 1 - config.contrast_max(), 1 + config.contrast_max());
  const double log_gamma_max = std::log1p(config.gamma_max());
  drawn.gamma = std::exp(Uniform(engine, -log_gamma_max, log_gamma_max));
  drawn.noise_seed = engine();
  drawn.exposure_ev = Uniform(engine, config.exposure_ev_min(), config.exposure_ev_max());
  drawn.shot_noise = Uniform(engine, 0.0, config.shot_noise_max());
  drawn.read_noise = Uniform(engine, 0.0, config.read_noise_max());
  for (double& gain : drawn.white_balance) {
    gain = Uniform(engine, 1 - config.white_balance_max(), 1 + config.white_balance_max());
  }
  drawn.clipped_tone = Uniform(engine, 0, 1) < config.clipped_tone_probability();
  drawn.saturation = Uniform(engine, config.saturation_min(), config.saturation_max());
  return config.enabled() ? drawn : SensorEffects{};
}

void ApplySensorEffects(const SensorEffects& effects, cv::Mat* image) {
  if (image == nullptr || image->empty() ||
      (image->type() != CV_8UC1 && image->type() != CV_8UC3)) {
    throw std::runtime_error(
        "ApplySensorEffects: the image must be a non-empty CV_8UC1 or CV_8UC3 image");
  }
  if (!(effects.gaussian_sigma >= 0) || !(effects.salt_pepper_fraction >= 0) ||
      !(effects.salt_pepper_fraction <= 1) || !(effects.contrast > 0) || !(effects.gamma > 0)) {
    throw std::runtime_error("ApplySensorEffects: effects out of range (gaussian_sigma " +
                             std::to_string(effects.gaussian_sigma) + ", salt_pepper_fraction " +
                             std::to_string(effects.salt_pepper_fraction) + ", contrast " +
                             std::to_string(effects.contrast) + ", gamma " +
                             std::to_string(effects.gamma) +
                             "); need sigma >= 0, fraction in [0, 1], contrast and gamma > 0");
  }
  // optics: defocus blur.
  if (effects.blur_sigma_px >= kMinBlurSigmaPx) {
    cv::GaussianBlur(*image, *image, cv::Size(), effects.blur_sigma_px, effects.blur_sigma_px,
                     cv::BORDER_REFLECT_101);
  }
  // exposure and response: gamma, contrast, brightness in one table.
  if (effects.gamma != 1 || effects.contrast != 1 || effects.brightness != 0) {
    cv::LUT(*image, ResponseTable(effects), *image);
  }
  // read-out noise.
  if (effects.gaussian_sigma > 0)
    AddGaussianNoise(effects.gaussian_sigma, effects.noise_seed, image);
  // dead and hot pixels.
  if (effects.salt_pepper_fraction > 0) {
    AddSaltAndPepper(effects.salt_pepper_fraction, effects.noise_seed, image);
  }
}

double AcesFilmic(double x) {
  x = std::max(x, 0.0);
  return std::clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

void AddLinearNoise(const SensorEffects& effects, cv::Mat* linear) {
  if (linear == nullptr || linear->empty() ||
      (linear->type() != CV_32FC1 && linear->type() != CV_32FC3) || !linear->isContinuous()) {
    throw std::runtime_error("AddLinearNoise: need a non-empty continuous CV_32FC1 or CV_32FC3");
  }
  const float shot = static_cast<float>(effects.shot_noise);
  const float read_variance = static_cast<float>(effects.read_noise * effects.read_noise);
  if (shot == 0 && read_variance == 0) return;
  const std::array<float, kNormalTableSize>& normal = NormalTable();
  const int values_per_row = linear->cols * linear->channels();
  const int streams = (linear->rows + kNoiseRowsPerStream - 1) / kNoiseRowsPerStream;
  cv::parallel_for_(cv::Range(0, streams), [&](const cv::Range& range) {
    for (int stream = range.start; stream < range.end; ++stream) {
      // one stream per block of rows, apart from the display-space noise's streams
      SplitMix64 rng(Mix64(effects.noise_seed ^ (0x1f83d9abfb41bd6bULL * (stream + 1))));
      const int row_end = std::min(linear->rows, (stream + 1) * kNoiseRowsPerStream);
      for (int y = stream * kNoiseRowsPerStream; y < row_end; ++y) {
        float* row = linear->ptr<float>(y);
        for (int i = 0; i < values_per_row;) {
          uint64_t bits = rng.Next();
          for (int k = 0; k < 64 / kNormalTableBits && i < values_per_row; ++k, ++i) {
            const float sigma = std::sqrt(shot * std::max(row[i], 0.f) + read_variance);
            row[i] += sigma * normal[bits & (kNormalTableSize - 1)];
            bits >>= kNormalTableBits;
          }
        }
      }
    }
  });
}

cv::Mat DevelopLinearImage(const SensorEffects& effects, const cv::Mat& linear_rgb, bool gray) {
  if (linear_rgb.empty() || linear_rgb.type() != CV_32FC3) {
    throw std::runtime_error("DevelopLinearImage: the image must be a non-empty CV_32FC3 image");
  }
  const double* balance = effects.white_balance;
  if (!std::isfinite(effects.exposure_ev) || !(effects.shot_noise >= 0) ||
      !(effects.read_noise >= 0) || !std::isfinite(effects.shot_noise) ||
      !std::isfinite(effects.read_noise) ||
      !(balance[0] > 0 && balance[1] > 0 && balance[2] > 0) ||
      !std::isfinite(balance[0] + balance[1] + balance[2]) || !(effects.saturation >= 0) ||
      !std::isfinite(effects.saturation)) {
    throw std::runtime_error(
        "DevelopLinearImage: exposure_ev " + std::to_string(effects.exposure_ev) + ", shot_noise " +
        std::to_string(effects.shot_noise) + ", read_noise " + std::to_string(effects.read_noise) +
        ", white balance " + std::to_string(balance[0]) + "/" + std::to_string(balance[1]) + "/" +
        std::to_string(balance[2]) + ", saturation " + std::to_string(effects.saturation) +
        " out of range; need finite values, noise >= 0, gains > 0, saturation >= 0");
  }
  // optics, then gray and exposure in one pass, in linear light
  const cv::Mat* source = &linear_rgb;
  cv::Mat blurred;
  if (effects.blur_sigma_px >= kMinBlurSigmaPx) {
    cv::GaussianBlur(linear_rgb, blurred, cv::Size(), effects.blur_sigma_px, effects.blur_sigma_px,
                     cv::BORDER_REFLECT_101);
    source = &blurred;
  }
  const float exposure = static_cast<float>(std::exp2(effects.exposure_ev));
  const cv::Vec3f gains(static_cast<float>(balance[0]), static_cast<float>(balance[1]),
                        static_cast<float>(balance[2]));
  cv::Mat signal;
  if (gray) {
    cv::transform(*source, signal,
                  cv::Matx13f(0.2126f * gains[0], 0.7152f * gains[1], 0.0722f * gains[2]) *
                      exposure);
  } else if (gains == cv::Vec3f(1, 1, 1) && effects.saturation == 1) {
    source->convertTo(signal, CV_32F, exposure);
  } else {
    // saturation about the luminance: s I + (1 - s) [1 1 1]^T [0.2126 0.7152 0.0722]
    const float s = static_cast<float>(effects.saturation);
    const cv::Matx13f luma(0.2126f, 0.7152f, 0.0722f);
    const cv::Matx33f toward_grey =
        s * cv::Matx33f::eye() + (1 - s) * cv::Matx31f(1, 1, 1) * luma;
    cv::transform(*source, signal, toward_grey * cv::Matx33f::diag(gains) * exposure);
  }
  // the sensor's noise
  AddLinearNoise(effects, &signal);

  // tone curve (filmic, or clipped at white) and sRGB encoding through one table over
  // sqrt(signal) in [0, 4]
  constexpr int kSteps = 4096;  // table entries per unit of sqrt(signal)
  constexpr int kEntries = 4 * kSteps + 1;
  const auto make_table = [](bool filmic) {
    std::array<uint8_t, kEntries> out;
    for (int i = 0; i < kEntries; ++i) {
      const double t = static_cast<double>(i) / kSteps;
      const double y = filmic ? AcesFilmic(t * t) : std::min(t * t, 1.0);
      const double display = y <= 0.0031308 ? 12.92 * y : 1.055 * std::pow(y, 1 / 2.4) - 0.055;
      out[i] = static_cast<uint8_t>(std::lround(255 * std::clamp(display, 0.0, 1.0)));
    }
    return out;
  };
  static const std::array<uint8_t, kEntries> filmic_table = make_table(true);
  static const std::array<uint8_t, kEntries> clipped_table = make_table(false);
  const std::array<uint8_t, kEntries>& table = effects.clipped_tone ? clipped_table : filmic_table;
  cv::Mat image(signal.rows, signal.cols, gray ? CV_8UC1 : CV_8UC3);
  const int values_per_row = signal.cols * signal.channels();
  cv::parallel_for_(cv::Range(0, signal.rows), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const float* in = signal.ptr<float>(y);
      uint8_t* out = image.ptr<uint8_t>(y);
      for (int i = 0; i < values_per_row; ++i) {
        const float t = std::sqrt(std::max(in[i], 0.f)) * kSteps + 0.5f;
        out[i] = t < kEntries - 1 ? table[static_cast<int>(t)] : table[kEntries - 1];  // NaN: white
      }
    }
  });

  // the camera's response settings and dead pixels, as in display space
  SensorEffects display = effects;
  display.gaussian_sigma = 0;
  display.blur_sigma_px = 0;
  ApplySensorEffects(display, &image);
  return image;
}

}  // namespace stackgen
