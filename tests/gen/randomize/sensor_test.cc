#include "gen/randomize/sensor.h"

#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

// a reproducible image of random bytes.
cv::Mat RandomImage(int type, uint64_t seed) {
  cv::Mat image(480, 640, type);
  cv::RNG(seed).fill(image, cv::RNG::UNIFORM, 0, 256);
  return image;
}

// a checkerboard of 0 and 255, `side` pixels per square.
cv::Mat Checker(int side) {
  cv::Mat image(480, 640, CV_8UC1);
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      image.at<uchar>(y, x) = ((x / side + y / side) % 2) ? 255 : 0;
    }
  }
  return image;
}

// the sum of squared differences of adjacent pixels: the image's high-frequency energy.
double HighFrequencyEnergy(const cv::Mat& image) {
  cv::Mat as_float;
  image.convertTo(as_float, CV_64F);
  const cv::Mat dx = as_float.colRange(1, image.cols) - as_float.colRange(0, image.cols - 1);
  const cv::Mat dy = as_float.rowRange(1, image.rows) - as_float.rowRange(0, image.rows - 1);
  return dx.dot(dx) + dy.dot(dy);
}

// the mean of `gray` after applying `effects` to a uniform image of that value.
double MeanAfter(const SensorEffects& effects, int gray) {
  cv::Mat image(48, 64, CV_8UC1, cv::Scalar(gray));
  ApplySensorEffects(effects, &image);
  return cv::mean(image)[0];
}

// identity effects leave colour and gray images bit-identical, whatever the noise seed.
TEST(SensorTest, IdentityLeavesTheImageBitIdentical) {
  for (const int type : {CV_8UC1, CV_8UC3}) {
    const cv::Mat original = RandomImage(type, 1);
    cv::Mat image = original.clone();
    SensorEffects effects;
    effects.blur_sigma_px = 0.29;  // below the blur threshold
    effects.noise_seed = 12345;
    ApplySensorEffects(effects, &image);
    EXPECT_EQ(cv::norm(image, original, cv::NORM_INF), 0);
  }
}

// Gaussian noise of sigma s on mid-gray gives a residual with std within 10 % of s (rounding to
// integers adds about 1/12 to the variance) and a mean within 4 standard errors of 0, per channel.
TEST(SensorTest, GaussianNoiseHasTheAskedStd) {
  for (const double sigma : {1.0, 5.0, 20.0}) {
    for (const int type : {CV_8UC1, CV_8UC3}) {
      cv::Mat image(480, 640, type, cv::Scalar::all(128));
      SensorEffects effects;
      effects.gaussian_sigma = sigma;
      effects.noise_seed = 7;
      ApplySensorEffects(effects, &image);
      cv::Mat residual;
      image.convertTo(residual, CV_64F, 1, -128);
      cv::Scalar mean;
      cv::Scalar stddev;
      cv::meanStdDev(residual, mean, stddev);
      for (int c = 0; c < image.channels(); ++c) {
        EXPECT_NEAR(stddev[c], sigma, 0.1 * sigma) << sigma << " channel " << c;
        EXPECT_NEAR(mean[c], 0, 4 * sigma / std::sqrt(image.total())) << sigma << " channel " << c;
      }
    }
  }
}

// salt and pepper with fraction f sets about f x N pixels (all channels) to 0 or 255, half each.
TEST(SensorTest, SaltAndPepperHitsTheAskedFraction) {
  for (const double fraction : {0.001, 0.01, 0.1}) {
    cv::Mat image(480, 640, CV_8UC3, cv::Scalar::all(128));
    SensorEffects effects;
    effects.salt_pepper_fraction = fraction;
    effects.noise_seed = 8;
    ApplySensorEffects(effects, &image);
    cv::Mat black;
    cv::Mat white;
    cv::inRange(image, cv::Scalar::all(0), cv::Scalar::all(0), black);
    cv::inRange(image, cv::Scalar::all(255), cv::Scalar::all(255), white);
    const double expected = fraction * image.total();
    const int hit = cv::countNonZero(black) + cv::countNonZero(white);
    // draws with replacement: a few pixels are hit twice (expected / 2 x fraction of them).
    EXPECT_NEAR(hit, expected * (1 - fraction / 2), 0.05 * expected) << fraction;
    EXPECT_NEAR(cv::countNonZero(black), expected / 2, 0.1 * expected) << fraction;
    // every other pixel is untouched.
    cv::Mat gray;
    cv::inRange(image, cv::Scalar::all(128), cv::Scalar::all(128), gray);
    EXPECT_EQ(cv::countNonZero(gray) + hit, static_cast<int>(image.total()));
  }
}

// blur lowers the high-frequency energy of a checkerboard, more with a larger sigma.
TEST(SensorTest, BlurLowersHighFrequencyEnergy) {
  const cv::Mat checker = Checker(4);
  const double before = HighFrequencyEnergy(checker);
  double previous = before;
  for (const double sigma : {0.5, 1.0, 2.0}) {
    cv::Mat image = checker.clone();
    SensorEffects effects;
    effects.blur_sigma_px = sigma;
    ApplySensorEffects(effects, &image);
    const double after = HighFrequencyEnergy(image);
    EXPECT_LT(after, 0.8 * previous) << sigma;
    previous = after;
  }
  EXPECT_LT(previous, 0.05 * before);
}

// brightness adds 255 x offset, contrast scales about 127.5, gamma bends as v^gamma: the mean
// of a uniform image moves to the computed value (rounded).
TEST(SensorTest, ResponseMovesTheMean) {
  SensorEffects brighter;
  brighter.brightness = 0.1;
  EXPECT_NEAR(MeanAfter(brighter, 100), 125.5, 0.51);
  brighter.brightness = -0.5;
  EXPECT_EQ(MeanAfter(brighter, 100), 0);  // saturates
  SensorEffects steeper;
  steeper.contrast = 1.5;
  EXPECT_NEAR(MeanAfter(steeper, 100), 86.25, 0.5);
  EXPECT_NEAR(MeanAfter(steeper, 200), 236.25, 0.5);
  EXPECT_EQ(MeanAfter(steeper, 127), 127);
  SensorEffects darker;
  darker.gamma = 2;
  EXPECT_NEAR(MeanAfter(darker, 100), 255 * std::pow(100 / 255.0, 2), 0.5);
  darker.gamma = 0.5;
  EXPECT_NEAR(MeanAfter(darker, 100), 255 * std::sqrt(100 / 255.0), 0.5);
  EXPECT_EQ(MeanAfter(darker, 0), 0);
  EXPECT_EQ(MeanAfter(darker, 255), 255);
}

// the same effects and noise seed give the same bytes; another seed other noise.
TEST(SensorTest, NoiseIsDeterministicBySeed) {
  SensorEffects effects;
  effects.gaussian_sigma = 4;
  effects.salt_pepper_fraction = 0.01;
  effects.blur_sigma_px = 1;
  effects.noise_seed = 99;
  const cv::Mat original = RandomImage(CV_8UC3, 2);
  cv::Mat a = original.clone();
  cv::Mat b = original.clone();
  cv::Mat c = original.clone();
  ApplySensorEffects(effects, &a);
  ApplySensorEffects(effects, &b);
  effects.noise_seed = 100;
  ApplySensorEffects(effects, &c);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0);
  EXPECT_GT(cv::norm(a, c, cv::NORM_L1), 0.5 * 4 * a.total() * 3);
}

// gray and colour images both work: the response acts alike on every channel, the noise is
// independent per channel; other types throw.
TEST(SensorTest, WorksOnGrayAndColour) {
  SensorEffects response;
  response.gamma = 1.3;
  response.contrast = 0.8;
  response.brightness = 0.05;
  response.blur_sigma_px = 1.5;
  const cv::Mat gray = RandomImage(CV_8UC1, 3);
  cv::Mat colour;
  cv::merge(std::vector<cv::Mat>{gray, gray, gray}, colour);
  cv::Mat gray_out = gray.clone();
  ApplySensorEffects(response, &gray_out);
  ApplySensorEffects(response, &colour);
  std::vector<cv::Mat> channels;
  cv::split(colour, channels);
  for (const cv::Mat& channel : channels) EXPECT_EQ(cv::norm(channel, gray_out, cv::NORM_INF), 0);
  EXPECT_GT(cv::norm(gray_out, gray, cv::NORM_INF), 0);

  SensorEffects noise;
  noise.gaussian_sigma = 5;
  noise.noise_seed = 4;
  cv::Mat flat(480, 640, CV_8UC3, cv::Scalar::all(128));
  ApplySensorEffects(noise, &flat);
  cv::split(flat, channels);
  EXPECT_GT(cv::norm(channels[0], channels[1], cv::NORM_L1), 3 * flat.total());

  cv::Mat wide(4, 4, CV_16UC1, cv::Scalar(0));
  EXPECT_THROW(ApplySensorEffects(noise, &wide), std::runtime_error);
  cv::Mat empty;
  EXPECT_THROW(ApplySensorEffects(noise, &empty), std::runtime_error);
}

// an image that is a view into a larger one (rows not contiguous) gets the same result as a
// copy of it, and the pixels around it stay untouched.
TEST(SensorTest, WorksOnViews) {
  SensorEffects effects;
  effects.gaussian_sigma = 3;
  effects.salt_pepper_fraction = 0.05;
  effects.noise_seed = 5;
  cv::Mat big = RandomImage(CV_8UC3, 6);
  const cv::Mat original = big.clone();
  const cv::Rect inner(10, 20, 300, 200);
  cv::Mat view = big(inner);
  cv::Mat copy = view.clone();
  ApplySensorEffects(effects, &view);
  ApplySensorEffects(effects, &copy);
  EXPECT_EQ(cv::norm(view, copy, cv::NORM_INF), 0);
  cv::Mat outside = big.clone();
  original(inner).copyTo(outside(inner));
  EXPECT_EQ(cv::norm(outside, original, cv::NORM_INF), 0);
}

// draws lie in the configured ranges, spread over them, and always take ten values; with
// enabled false the result is the identity after the same ten draws.
TEST(SensorTest, SamplingRangesAndDisabled) {
  config::SensorConfig config;
  std::mt19937_64 engine(10);
  double gamma_lo = INFINITY, gamma_hi = 0;
  for (int i = 0; i < 1000; ++i) {
    const SensorEffects drawn = SampleSensorEffects(config, engine);
    ASSERT_GE(drawn.gaussian_sigma, 0);
    ASSERT_LE(drawn.gaussian_sigma, 3);
    ASSERT_LE(drawn.salt_pepper_fraction, 0.001);
    ASSERT_LE(drawn.blur_sigma_px, 0.8);
    ASSERT_LE(std::abs(drawn.brightness), 0.08);
    ASSERT_LE(std::abs(drawn.contrast - 1), 0.15);
    ASSERT_GE(drawn.gamma, 1 / 1.2 - 1e-12);
    ASSERT_LE(drawn.gamma, 1.2 + 1e-12);
    ASSERT_LE(std::abs(drawn.exposure_ev), 0.5);
    ASSERT_GE(drawn.shot_noise, 0);
    ASSERT_LE(drawn.shot_noise, 0.0005);
    ASSERT_GE(drawn.read_noise, 0);
    ASSERT_LE(drawn.read_noise, 0.003);
    // white_balance_max 0 by default: the gains stay 1
    ASSERT_EQ(drawn.white_balance[0], 1);
    ASSERT_EQ(drawn.white_balance[2], 1);
    gamma_lo = std::min(gamma_lo, drawn.gamma);
    gamma_hi = std::max(gamma_hi, drawn.gamma);
  }
  EXPECT_LT(gamma_lo, 1 / 1.2 + 0.01);
  EXPECT_GT(gamma_hi, 1.2 - 0.01);

  config::SensorConfig disabled;
  disabled.set_enabled(false);
  std::mt19937_64 a(11);
  std::mt19937_64 b(11);
  const SensorEffects identity = SampleSensorEffects(disabled, a);
  const SensorEffects drawn = SampleSensorEffects(config, b);
  EXPECT_EQ(a, b);
  std::mt19937_64 reference(11);
  reference.discard(15);
  EXPECT_EQ(a, reference);
  EXPECT_GT(drawn.gaussian_sigma, 0);
  EXPECT_EQ(identity.gaussian_sigma, 0);
  EXPECT_EQ(identity.salt_pepper_fraction, 0);
  EXPECT_EQ(identity.blur_sigma_px, 0);
  EXPECT_EQ(identity.brightness, 0);
  EXPECT_EQ(identity.contrast, 1);
  EXPECT_EQ(identity.gamma, 1);
  EXPECT_EQ(identity.exposure_ev, 0);
  EXPECT_EQ(identity.read_noise, 0);
  const cv::Mat original = RandomImage(CV_8UC3, 12);
  cv::Mat image = original.clone();
  ApplySensorEffects(identity, &image);
  EXPECT_EQ(cv::norm(image, original, cv::NORM_INF), 0);
}

// the linear path: black stays black, white saturates, mid grey follows the ACES curve and sRGB;
// exposure is a factor of two per stop; gray is the Rec. 709 luminance
TEST(SensorTest, DevelopsLinearLightThroughTheToneCurve) {
  cv::Mat linear(4, 4, CV_32FC3, cv::Scalar(0.18f, 0.18f, 0.18f));
  linear.at<cv::Vec3f>(0, 0) = cv::Vec3f(0, 0, 0);
  linear.at<cv::Vec3f>(0, 1) = cv::Vec3f(50, 50, 50);
  linear.at<cv::Vec3f>(0, 2) = cv::Vec3f(1, 0, 0);
  const SensorEffects identity;
  const cv::Mat rgb = DevelopLinearImage(identity, linear, false);
  ASSERT_EQ(rgb.type(), CV_8UC3);
  EXPECT_EQ(rgb.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(rgb.at<cv::Vec3b>(0, 1), cv::Vec3b(255, 255, 255));
  const auto expected = [](double x) {
    const double y = AcesFilmic(x);
    return static_cast<int>(std::lround(255 * (1.055 * std::pow(y, 1 / 2.4) - 0.055)));
  };
  EXPECT_NEAR(rgb.at<cv::Vec3b>(2, 2)[1], expected(0.18), 0.51);
  SensorEffects brighter;
  brighter.exposure_ev = 1;
  EXPECT_NEAR(DevelopLinearImage(brighter, linear, false).at<cv::Vec3b>(2, 2)[1], expected(0.36),
              0.51);
  const cv::Mat gray = DevelopLinearImage(identity, linear, true);
  ASSERT_EQ(gray.type(), CV_8UC1);
  EXPECT_NEAR(gray.at<uint8_t>(0, 2), expected(0.2126), 0.51);
  EXPECT_THROW(DevelopLinearImage(identity, cv::Mat(4, 4, CV_8UC3), false), std::runtime_error);
  SensorEffects bad;
  bad.read_noise = -1;
  EXPECT_THROW(DevelopLinearImage(bad, linear, false), std::runtime_error);
}

// a white balance off multiplies each channel of linear light before the tone curve: red x 2 is
// mid grey exposed a stop brighter, blue stays; gray takes the balanced channels' luminance; the
// gains are drawn within white_balance_max of 1
TEST(SensorTest, WhiteBalanceScalesEachChannel) {
  const cv::Mat linear(4, 4, CV_32FC3, cv::Scalar(0.18f, 0.18f, 0.18f));
  const auto expected = [](double x) {
    const double y = AcesFilmic(x);
    return static_cast<int>(std::lround(255 * (1.055 * std::pow(y, 1 / 2.4) - 0.055)));
  };
  SensorEffects warm;
  warm.white_balance[0] = 2;
  const cv::Vec3b pixel = DevelopLinearImage(warm, linear, false).at<cv::Vec3b>(1, 1);
  EXPECT_NEAR(pixel[0], expected(0.36), 0.51);
  EXPECT_NEAR(pixel[2], expected(0.18), 0.51);
  EXPECT_NEAR(DevelopLinearImage(warm, linear, true).at<uint8_t>(1, 1),
              expected(0.18 * (1 + 0.2126)), 0.51);
  SensorEffects bad;
  bad.white_balance[1] = 0;
  EXPECT_THROW(DevelopLinearImage(bad, linear, false), std::runtime_error);

  config::SensorConfig config;
  config.set_white_balance_max(0.1);
  std::mt19937_64 engine(4);
  double lowest = 2, highest = 0;
  for (int i = 0; i < 500; ++i) {
    const SensorEffects drawn = SampleSensorEffects(config, engine);
    for (const double gain : drawn.white_balance) {
      ASSERT_GE(gain, 0.9);
      ASSERT_LE(gain, 1.1);
      lowest = std::min(lowest, gain);
      highest = std::max(highest, gain);
    }
  }
  EXPECT_LT(lowest, 0.91);
  EXPECT_GT(highest, 1.09);
}

// a saturation moves each pixel's linear colour toward its Rec. 709 luminance (0: grey, the
// luminance kept) or away from it (2: twice as far), 1 leaves the bytes as they were; gray
// images ignore it; drawn uniformly within [saturation_min, saturation_max]
TEST(SensorTest, SaturationMovesColoursAboutTheirLuminance) {
  const cv::Mat linear(4, 4, CV_32FC3, cv::Scalar(0.5f, 0.1f, 0.1f));
  const auto expected = [](double x) {
    const double y = AcesFilmic(x);
    return static_cast<int>(std::lround(255 * (1.055 * std::pow(y, 1 / 2.4) - 0.055)));
  };
  const double luminance = 0.2126 * 0.5 + 0.7152 * 0.1 + 0.0722 * 0.1;
  SensorEffects grey;
  grey.saturation = 0;
  const cv::Vec3b flat = DevelopLinearImage(grey, linear, false).at<cv::Vec3b>(1, 1);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(flat[c], expected(luminance), 0.51) << c;
  SensorEffects vivid;
  vivid.saturation = 2;
  const cv::Vec3b pixel = DevelopLinearImage(vivid, linear, false).at<cv::Vec3b>(1, 1);
  EXPECT_NEAR(pixel[0], expected(luminance + 2 * (0.5 - luminance)), 0.51);
  EXPECT_NEAR(pixel[1], expected(luminance + 2 * (0.1 - luminance)), 0.51);
  const SensorEffects identity;
  SensorEffects one;
  one.saturation = 1;
  one.white_balance[0] = 1.1;
  SensorEffects balanced;
  balanced.white_balance[0] = 1.1;
  EXPECT_EQ(cv::norm(DevelopLinearImage(one, linear, false),
                     DevelopLinearImage(balanced, linear, false), cv::NORM_INF),
            0);
  EXPECT_EQ(cv::norm(DevelopLinearImage(grey, linear, true),
                     DevelopLinearImage(identity, linear, true), cv::NORM_INF),
            0);
  SensorEffects bad;
  bad.saturation = -0.1;
  EXPECT_THROW(DevelopLinearImage(bad, linear, false), std::runtime_error);

  config::SensorConfig config;
  std::mt19937_64 engine(5);
  EXPECT_EQ(SampleSensorEffects(config, engine).saturation, 1);
  config.set_saturation_min(0.4);
  config.set_saturation_max(1.3);
  double lowest = 2, highest = 0;
  for (int i = 0; i < 500; ++i) {
    const double drawn = SampleSensorEffects(config, engine).saturation;
    ASSERT_GE(drawn, 0.4);
    ASSERT_LE(drawn, 1.3);
    lowest = std::min(lowest, drawn);
    highest = std::max(highest, drawn);
  }
  EXPECT_LT(lowest, 0.42);
  EXPECT_GT(highest, 1.28);
}

// a clipped tone is plain sRGB up to white and white beyond, where the filmic curve keeps a
// shoulder: mid grey brighter, 0.9 white, 1.5 white; drawn as often as the chance says
TEST(SensorTest, ClippedToneIsPlainSrgb) {
  cv::Mat linear(1, 3, CV_32FC3);
  linear.at<cv::Vec3f>(0, 0) = cv::Vec3f::all(0.18f);
  linear.at<cv::Vec3f>(0, 1) = cv::Vec3f::all(0.9f);
  linear.at<cv::Vec3f>(0, 2) = cv::Vec3f::all(1.5f);
  SensorEffects clipped;
  clipped.clipped_tone = true;
  const cv::Mat plain = DevelopLinearImage(clipped, linear, true);
  const cv::Mat filmic = DevelopLinearImage(SensorEffects(), linear, true);
  const auto srgb = [](double y) {
    return static_cast<int>(std::lround(255 * (1.055 * std::pow(y, 1 / 2.4) - 0.055)));
  };
  EXPECT_NEAR(plain.at<uint8_t>(0, 0), srgb(0.18), 0.51);
  EXPECT_NEAR(plain.at<uint8_t>(0, 1), srgb(0.9), 0.51);
  EXPECT_EQ(plain.at<uint8_t>(0, 2), 255);
  EXPECT_LT(filmic.at<uint8_t>(0, 1), plain.at<uint8_t>(0, 1) - 10);

  config::SensorConfig config;
  config.set_clipped_tone_probability(0.3);
  std::mt19937_64 engine(6);
  int count = 0;
  for (int i = 0; i < 1000; ++i) count += SampleSensorEffects(config, engine).clipped_tone;
  EXPECT_NEAR(count, 300, 60);
}

// noise in linear light has the variance of shot noise (growing with the signal) plus read
// noise, the same bytes for the same seed, and other bytes for another
TEST(SensorTest, LinearNoiseFollowsTheSignal) {
  SensorEffects effects;
  effects.shot_noise = 0.01;
  effects.read_noise = 0.02;
  effects.noise_seed = 5;
  for (const float signal : {0.f, 0.25f, 1.f}) {
    cv::Mat image(200, 300, CV_32FC1, cv::Scalar(signal));
    AddLinearNoise(effects, &image);
    cv::Scalar mean, std;
    cv::meanStdDev(image, mean, std);
    const double expected = std::sqrt(0.01 * signal + 0.02 * 0.02);
    EXPECT_NEAR(std[0], expected, 0.02 * expected) << "signal " << signal;
    EXPECT_NEAR(mean[0], signal, 0.05 * expected);
  }
  cv::Mat a(64, 64, CV_32FC3, cv::Scalar(0.5, 0.5, 0.5));
  cv::Mat b = a.clone();
  cv::Mat c = a.clone();
  AddLinearNoise(effects, &a);
  AddLinearNoise(effects, &b);
  effects.noise_seed = 6;
  AddLinearNoise(effects, &c);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0);
  EXPECT_GT(cv::norm(a, c, cv::NORM_INF), 0);
}

}  // namespace
}  // namespace stackgen
