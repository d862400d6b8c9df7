#include "gen/render/environment.h"

#include <cmath>
#include <fstream>
#include <string>

#include <ImfRgbaFile.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "tests/support/environments.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

// pixels and directions map back and forth; row 0 looks up, column 0 towards -x
TEST(EnvironmentTest, PixelsAndDirectionsAgree) {
  for (const double u : {0.0, 17.3, 255.0}) {
    for (const double v : {0.0, 60.5, 127.0}) {
      const Eigen::Vector2d back = PixelOfDirection(DirectionOfPixel(u, v, 256, 128), 256, 128);
      EXPECT_NEAR(back.x(), u, 1e-9);
      EXPECT_NEAR(back.y(), v, 1e-9);
    }
  }
  EXPECT_GT(DirectionOfPixel(128, 0, 256, 128).z(), 0.99);
  EXPECT_LT(DirectionOfPixel(0, 64, 256, 128).x(), -0.99);
}

// the DFG table: a smooth surface reflects all (f0 = 1) with no Fresnel peak head-on; no
// entry reflects more than it receives; single scattering loses energy as roughness grows
TEST(EnvironmentTest, DfgTableConservesEnergy) {
  const cv::Mat lut = ComputeDfgLut(32, 512);
  ASSERT_EQ(lut.type(), CV_32FC2);
  for (int j = 0; j < 32; ++j) {
    for (int i = 0; i < 32; ++i) {
      const cv::Vec2f e = lut.at<cv::Vec2f>(j, i);
      EXPECT_GE(e[0], 0.f);
      EXPECT_LE(e[0], e[1]);
      EXPECT_LE(e[1], 1.001f) << "n.v " << (i + 0.5) / 32 << ", roughness " << (j + 0.5) / 32;
    }
  }
  EXPECT_GT(lut.at<cv::Vec2f>(0, 31)[1], 0.99f);
  EXPECT_LT(lut.at<cv::Vec2f>(0, 31)[0], 0.01f);
  EXPECT_LT(lut.at<cv::Vec2f>(31, 16)[1], 0.9f);
  EXPECT_LT(lut.at<cv::Vec2f>(31, 16)[1], lut.at<cv::Vec2f>(8, 16)[1]);
}

// a uniform environment stays uniform at every roughness, and its irradiance is that radiance
TEST(EnvironmentTest, UniformEnvironmentPrefiltersToItself) {
  const PrefilteredEnvironment p = Prefilter(testing::EnvironmentOf([](const Eigen::Vector3d&) {
                                               return Eigen::Vector3f(0.2f, 0.5f, 1.f);
                                             }),
                                             128);
  ASSERT_EQ(p.levels.size(), static_cast<size_t>(PrefilteredEnvironment::kLevels));
  for (size_t k = 0; k < p.levels.size(); ++k) {
    EXPECT_EQ(p.levels[k].cols, 128 >> k);
    double lo = 0, hi = 0;
    cv::minMaxLoc(p.levels[k].reshape(1).col(2), &lo, &hi);
    EXPECT_NEAR(lo, 1.0, 1e-3) << "level " << k;
    EXPECT_NEAR(hi, 1.0, 1e-3) << "level " << k;
  }
  for (const Eigen::Vector3d& n :
       {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0.3, -0.5, -0.8)}) {
    const Eigen::Vector3f e = EvaluateIrradianceSh(p.irradiance_sh, n);
    EXPECT_NEAR(e.x(), 0.2f, 0.005f);
    EXPECT_NEAR(e.z(), 1.f, 0.02f);
  }
}

// under a white sky above the horizon and black below, a white matte surface facing up shows
// 1, facing sideways 1/2, facing down 0 (nine harmonics: within a few per cent); rough levels
// blur the horizon but keep the zenith bright
TEST(EnvironmentTest, SkyIrradianceFollowsTheCosineLaw) {
  const PrefilteredEnvironment p = Prefilter(
      testing::EnvironmentOf(
          [](const Eigen::Vector3d& d) { return Eigen::Vector3f::Constant(d.z() > 0 ? 1 : 0); },
          128),
      256);
  EXPECT_NEAR(EvaluateIrradianceSh(p.irradiance_sh, {0, 0, 1}).x(), 1.0, 0.06);
  EXPECT_NEAR(EvaluateIrradianceSh(p.irradiance_sh, {1, 0, 0}).x(), 0.5, 0.03);
  EXPECT_NEAR(EvaluateIrradianceSh(p.irradiance_sh, {0, 0, -1}).x(), 0.0, 0.06);
  const cv::Mat& rough = p.levels.back();
  EXPECT_GT(rough.at<cv::Vec3f>(0, 0)[0], 0.9f);
  const float at_horizon = rough.at<cv::Vec3f>(rough.rows / 2, 0)[0];
  EXPECT_GT(at_horizon, 0.2f);
  EXPECT_LT(at_horizon, 0.8f);
}

// a hall is a pure function of its variant, with bright lamps overhead and dim surroundings
TEST(EnvironmentTest, HallsAreReproducibleAndLitFromAbove) {
  const EnvironmentMap a = MakeHallEnvironment(7, 64);
  const EnvironmentMap b = MakeHallEnvironment(7, 64);
  const EnvironmentMap c = MakeHallEnvironment(8, 64);
  ASSERT_EQ(a.radiance.size(), cv::Size(128, 64));
  EXPECT_EQ(cv::norm(a.radiance, b.radiance, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a.radiance, c.radiance, cv::NORM_INF), 0.0);
  double hi = 0;
  cv::minMaxLoc(a.radiance.rowRange(0, 32).reshape(1), nullptr, &hi);
  EXPECT_GT(hi, 5.0);
  const cv::Scalar lower = cv::mean(a.radiance.rowRange(40, 64));
  EXPECT_LT(lower[1], 0.6);
  EXPECT_THROW(MakeHallEnvironment(0, 4), std::invalid_argument);
}

// Radiance and OpenEXR files load as linear RGB; a bad file is refused naming it
TEST(EnvironmentTest, LoadsHdrAndExrFiles) {
  const testing::ScratchDir scratch("environment");  // removed at the end, its own name
  const std::string dir = scratch.path() + "/";
  cv::Mat bgr(32, 64, CV_32FC3, cv::Scalar(0.25, 0.5, 4.0));  // B, G, R
  ASSERT_TRUE(cv::imwrite(dir + "sky.hdr", bgr));
  const EnvironmentMap hdr = LoadEnvironment(dir + "sky.hdr");
  ASSERT_EQ(hdr.radiance.size(), cv::Size(64, 32));
  EXPECT_NEAR(hdr.radiance.at<cv::Vec3f>(3, 3)[0], 4.0f, 0.05f);
  EXPECT_NEAR(hdr.radiance.at<cv::Vec3f>(3, 3)[2], 0.25f, 0.01f);

  {
    std::vector<Imf::Rgba> pixels(48 * 16, Imf::Rgba(2.f, 1.f, 0.5f, 1.f));
    Imf::RgbaOutputFile file((dir + "wide.exr").c_str(), 48, 16, Imf::WRITE_RGBA);
    file.setFrameBuffer(pixels.data(), 1, 48);
    file.writePixels(16);
  }
  const EnvironmentMap exr = LoadEnvironment(dir + "wide.exr");
  EXPECT_EQ(exr.radiance.size(), cv::Size(32, 16));  // resampled to 2:1
  EXPECT_NEAR(exr.radiance.at<cv::Vec3f>(8, 8)[0], 2.f, 1e-3f);
  EXPECT_NEAR(exr.radiance.at<cv::Vec3f>(8, 8)[2], 0.5f, 1e-3f);

  std::ofstream(dir + "broken.exr") << "not an image";
  try {
    LoadEnvironment(dir + "broken.exr");
    ADD_FAILURE() << "no error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("broken.exr"), std::string::npos) << error.what();
  }
  EXPECT_THROW(LoadEnvironment(dir + "missing.hdr"), std::runtime_error);
  EXPECT_THROW(ListEnvironmentFiles(dir + "no-such-folder"), std::runtime_error);
}

}  // namespace
}  // namespace stackgen
