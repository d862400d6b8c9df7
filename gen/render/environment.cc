// Image-based light for the renderer, computed on the CPU once per environment: the split-sum
// approximation of Karis, "Real Shading in Unreal Engine 4" (SIGGRAPH 2013 course notes):
// radiance prefiltered by a GGX lobe per roughness level (filtered importance sampling, Krivanek
// and Colbert, GPU Gems 3 ch. 20), a BRDF lookup table, and the irradiance as nine spherical
// harmonics (Ramamoorthi and Hanrahan 2001), as google/filament does (docs/Filament.md, 5.3).
#include "gen/render/environment.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <random>
#include <stdexcept>

#include <ImfArray.h>
#include <ImfRgbaFile.h>
#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "contract/splitmix.h"

namespace stackgen {
namespace {

constexpr double kPi = M_PI;

// the i-th of n points of the Hammersley set in [0, 1)^2
Eigen::Vector2d Hammersley(uint32_t i, uint32_t n) {
  uint32_t bits = i;
  bits = (bits << 16u) | (bits >> 16u);
  bits = ((bits & 0x55555555u) << 1u) | ((bits & 0xAAAAAAAAu) >> 1u);
  bits = ((bits & 0x33333333u) << 2u) | ((bits & 0xCCCCCCCCu) >> 2u);
  bits = ((bits & 0x0F0F0F0Fu) << 4u) | ((bits & 0xF0F0F0F0u) >> 4u);
  bits = ((bits & 0x00FF00FFu) << 8u) | ((bits & 0xFF00FF00u) >> 8u);
  return {(i + 0.5) / n, bits * 2.3283064365386963e-10};
}

// a GGX-distributed half vector (tangent frame, z = normal) for alpha = roughness^2
Eigen::Vector3d SampleGgx(const Eigen::Vector2d& xi, double alpha) {
  const double a2 = alpha * alpha;
  const double cos_theta = std::sqrt((1 - xi.y()) / (1 + (a2 - 1) * xi.y()));
  const double sin_theta = std::sqrt(std::max(0.0, 1 - cos_theta * cos_theta));
  const double phi = 2 * kPi * xi.x();
  return {sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta};
}

// the GGX normal distribution function (Walter et al. 2007)
double DistributionGgx(double n_dot_h, double alpha) {
  const double a2 = alpha * alpha;
  const double f = n_dot_h * n_dot_h * (a2 - 1) + 1;
  return a2 / (kPi * f * f);
}

// Smith's height-correlated visibility G / (4 n.l n.v) for GGX (Heitz 2014)
double VisibilitySmithGgxCorrelated(double n_dot_v, double n_dot_l, double alpha) {
  const double a2 = alpha * alpha;
  const double gv = n_dot_l * std::sqrt(n_dot_v * n_dot_v * (1 - a2) + a2);
  const double gl = n_dot_v * std::sqrt(n_dot_l * n_dot_l * (1 - a2) + a2);
  return 0.5 / (gv + gl);
}

// an orthonormal frame whose third column is `n`
Eigen::Matrix3d FrameAround(const Eigen::Vector3d& n) {
  const Eigen::Vector3d helper =
      std::abs(n.z()) < 0.999 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x = helper.cross(n).normalized();
  Eigen::Matrix3d frame;
  frame << x, n.cross(x), n;
  return frame;
}

// a direction's azimuth phi (from +x towards +y) and polar angle theta (from +z), radians
struct Angles {
  double phi;
  double theta;
};

Angles AnglesOf(const Eigen::Vector3d& direction) {
  const Eigen::Vector3d d = direction.normalized();
  return {std::atan2(d.y(), d.x()), std::acos(std::clamp(d.z(), -1.0, 1.0))};
}

// the pixel of an equirectangular image of width x height at those angles
Eigen::Vector2d PixelOfAngles(const Angles& angles, int width, int height) {
  return {(angles.phi + kPi) / (2 * kPi) * width - 0.5, angles.theta / kPi * height - 0.5};
}

// bilinear lookup of an equirectangular CV_32FC3 image: wraps around in azimuth, clamps at the
// poles
Eigen::Vector3f SampleBilinear(const cv::Mat& image, const Angles& angles) {
  const Eigen::Vector2d p = PixelOfAngles(angles, image.cols, image.rows);
  const double v = std::clamp(p.y(), 0.0, image.rows - 1.0);
  const int u0 = static_cast<int>(std::floor(p.x()));
  const int v0 = std::min(static_cast<int>(std::floor(v)), image.rows - 1);
  const double fu = p.x() - u0;
  const double fv = v - v0;
  const int v1 = std::min(v0 + 1, image.rows - 1);
  const auto at = [&image](int row, int column) {
    column = ((column % image.cols) + image.cols) % image.cols;
    const cv::Vec3f& c = image.at<cv::Vec3f>(row, column);
    return Eigen::Vector3f(c[0], c[1], c[2]);
  };
  return static_cast<float>((1 - fv) * (1 - fu)) * at(v0, u0) +
         static_cast<float>((1 - fv) * fu) * at(v0, u0 + 1) +
         static_cast<float>(fv * (1 - fu)) * at(v1, u0) +
         static_cast<float>(fv * fu) * at(v1, u0 + 1);
}

Eigen::Vector3f SampleBilinear(const cv::Mat& image, const Eigen::Vector3d& direction) {
  return SampleBilinear(image, AnglesOf(direction));
}

// trilinear lookup in a pyramid of equirectangular images (level m halves level m - 1); the
// direction's angles are found once for both levels
Eigen::Vector3f SampleLod(const std::vector<cv::Mat>& pyramid, const Eigen::Vector3d& direction,
                          double lod) {
  lod = std::clamp(lod, 0.0, static_cast<double>(pyramid.size() - 1));
  const int m0 = static_cast<int>(std::floor(lod));
  const int m1 = std::min(m0 + 1, static_cast<int>(pyramid.size()) - 1);
  const float t = static_cast<float>(lod - m0);
  const Angles angles = AnglesOf(direction);
  return (1 - t) * SampleBilinear(pyramid[m0], angles) + t * SampleBilinear(pyramid[m1], angles);
}

// the 9 real spherical harmonics of bands 0..2 at a unit direction
std::array<double, 9> ShBasis(const Eigen::Vector3d& d) {
  return {0.282095,
          0.488603 * d.y(),
          0.488603 * d.z(),
          0.488603 * d.x(),
          1.092548 * d.x() * d.y(),
          1.092548 * d.y() * d.z(),
          0.315392 * (3 * d.z() * d.z() - 1),
          1.092548 * d.x() * d.z(),
          0.546274 * (d.x() * d.x() - d.y() * d.y())};
}

// a 2:1 copy of `image` of the given width, area-averaged when smaller, bilinear when larger
cv::Mat Resample(const cv::Mat& image, int width) {
  if (image.cols == width && image.rows * 2 == width) return image.clone();
  cv::Mat out;
  const bool smaller = width < image.cols;
  cv::resize(image, out, cv::Size(width, width / 2), 0, 0,
             smaller ? cv::INTER_AREA : cv::INTER_LINEAR);
  return out;
}

std::string Lowercase(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return text;
}

// OpenEXR's RGBA interface: any channel layout (RGB, RGBA, Y) as linear RGB floats
cv::Mat ReadExr(const std::string& path) {
  Imf::RgbaInputFile file(path.c_str());
  const Imath::Box2i window = file.dataWindow();
  const int width = window.max.x - window.min.x + 1;
  const int height = window.max.y - window.min.y + 1;
  if (width <= 0 || height <= 0) return cv::Mat();
  Imf::Array2D<Imf::Rgba> pixels(height, width);
  file.setFrameBuffer(&pixels[0][0] - window.min.x - window.min.y * width, 1, width);
  file.readPixels(window.min.y, window.max.y);
  cv::Mat out(height, width, CV_32FC3);
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const Imf::Rgba& p = pixels[v][u];
      out.at<cv::Vec3f>(v, u) = cv::Vec3f(p.r, p.g, p.b);
    }
  }
  return out;
}

}  // namespace

Eigen::Vector3d DirectionOfPixel(double u, double v, int width, int height) {
  const double phi = 2 * kPi * (u + 0.5) / width - kPi;
  const double theta = kPi * (v + 0.5) / height;
  return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
}

Eigen::Vector2d PixelOfDirection(const Eigen::Vector3d& direction, int width, int height) {
  return PixelOfAngles(AnglesOf(direction), width, height);
}

EnvironmentMap LoadEnvironment(const std::string& path) {
  // read: Radiance through OpenCV, OpenEXR through its own library
  const std::string extension = Lowercase(std::filesystem::path(path).extension().string());
  cv::Mat radiance;
  try {
    if (extension == ".exr") {
      radiance = ReadExr(path);
    } else if (extension == ".hdr") {
      cv::Mat bgr = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_COLOR);
      if (!bgr.empty()) {
        bgr.convertTo(bgr, CV_32FC3);
        cv::cvtColor(bgr, radiance, cv::COLOR_BGR2RGB);
      }
    } else {
      throw std::runtime_error("not a .hdr or .exr file");
    }
  } catch (const std::exception& error) {
    throw std::runtime_error("environment " + path + ": cannot read: " + error.what());
  }
  if (radiance.empty()) {
    throw std::runtime_error("environment " + path + ": cannot read it as an HDR image");
  }

  // every value finite and not negative
  for (int v = 0; v < radiance.rows; ++v) {
    const float* row = radiance.ptr<float>(v);
    for (int i = 0; i < radiance.cols * 3; ++i) {
      if (!std::isfinite(row[i]) || row[i] < 0) {
        throw std::runtime_error("environment " + path + ": pixel (" + std::to_string(i / 3) +
                                 ", " + std::to_string(v) + ") holds " + std::to_string(row[i]) +
                                 ", not a finite radiance >= 0");
      }
    }
  }
  EnvironmentMap out;
  out.name = path;
  out.radiance =
      radiance.cols == 2 * radiance.rows ? radiance : Resample(radiance, 2 * radiance.rows);
  return out;
}

std::vector<std::string> ListEnvironmentFiles(const std::string& folder) {
  std::error_code error;
  if (!std::filesystem::is_directory(folder, error)) {
    throw std::runtime_error("environment folder " + folder + " is missing or not a folder");
  }
  std::vector<std::string> files;
  for (const auto& entry : std::filesystem::directory_iterator(folder, error)) {
    const std::string extension = Lowercase(entry.path().extension().string());
    if (entry.is_regular_file() && (extension == ".hdr" || extension == ".exr")) {
      files.push_back(entry.path().string());
    }
  }
  if (error) throw std::runtime_error("environment folder " + folder + ": " + error.message());
  if (files.empty()) {
    throw std::runtime_error("environment folder " + folder + " holds no .hdr or .exr file");
  }
  std::sort(files.begin(), files.end());
  return files;
}

namespace {

// A procedural industrial hall around the origin (metres): its size, greys, light strips cut
// into lamps, and windows, as DrawHall draws them.
struct Hall {
  double half_length, half_width, ceiling, floor, ceiling_grey;
  Eigen::Vector3d wall;
  double wall_band, band_grey, floor_grey;
  bool strips_along_x;
  int strip_rows;
  double strip_width, lamp_length, lamp_gap, strip_offset, lamp_phase, lamp_radiance;
  Eigen::Vector3d lamp_tint;
  double window_bottom, window_top, window_radiance, pane_period;
  bool windows_on_x_walls;

  // The radiance a ray from the origin along `d` sees first: ceiling, floor or one of the walls.
  Eigen::Vector3d Radiance(const Eigen::Vector3d& d) const {
    const double strip_span = 2 * (strips_along_x ? half_width : half_length);
    const double strip_spacing = strip_span / strip_rows;
    double t = std::numeric_limits<double>::infinity();
    if (d.z() > 1e-9) t = std::min(t, ceiling / d.z());
    if (d.z() < -1e-9) t = std::min(t, floor / -d.z());
    if (std::abs(d.x()) > 1e-9) t = std::min(t, half_length / std::abs(d.x()));
    if (std::abs(d.y()) > 1e-9) t = std::min(t, half_width / std::abs(d.y()));
    const Eigen::Vector3d p = t * d;
    if (p.z() >= ceiling - 1e-6) {
      const double across = strips_along_x ? p.y() : p.x();
      const double along = strips_along_x ? p.x() : p.y();
      const double row = (across + strip_span / 2) / strip_spacing - 0.5 - strip_offset;
      const double to_row = std::abs(row - std::round(row)) * strip_spacing;
      const double period = lamp_length + lamp_gap;
      const double in_lamp = std::fmod(along / period + lamp_phase + 1000, 1.0) * period;
      if (to_row < strip_width / 2 && in_lamp < lamp_length) return lamp_radiance * lamp_tint;
      return Eigen::Vector3d::Constant(ceiling_grey);
    }
    if (p.z() <= -floor + 1e-6) return Eigen::Vector3d::Constant(floor_grey);
    // a wall: windows high up, a dark band low down
    const bool on_x_wall = std::abs(std::abs(p.x()) - half_length) < 1e-6;
    if (on_x_wall == windows_on_x_walls && p.z() > window_bottom && p.z() < window_top) {
      const double along = on_x_wall ? p.y() : p.x();
      if (std::fmod(along / pane_period + 1000.25, 1.0) < 0.8) {
        return window_radiance * Eigen::Vector3d(0.85, 0.95, 1.1);
      }
    }
    if (p.z() < wall_band - floor) return Eigen::Vector3d::Constant(band_grey);
    return wall;
  }
};

// The hall of `variant`, each value one draw of its own engine, in a fixed order.
Hall DrawHall(uint64_t variant) {
  Hall h{};
  std::mt19937_64 engine(SplitMixHash(variant ^ 0x68616c6cull));
  // one engine value per draw, the same on every platform (std::uniform_real_distribution's
  // results are left to the library)
  const auto uniform = [&engine](double lo, double hi) {
    return lo + (hi - lo) * (static_cast<double>(engine() >> 11) * 0x1.0p-53);
  };
  h.half_length = uniform(12, 40);  // m, along x
  h.half_width = uniform(8, 25);    // m, along y
  h.ceiling = uniform(3.5, 9);      // m above the table
  h.floor = 0.9;                    // m below the table
  h.ceiling_grey = uniform(0.03, 0.12);
  h.wall = Eigen::Vector3d::Constant(uniform(0.15, 0.45))
               .cwiseProduct(Eigen::Vector3d(uniform(0.9, 1.1), 1, uniform(0.85, 1.1)));
  h.wall_band = uniform(1.2, 2.2);  // m above the floor: a darker band below it
  h.band_grey = uniform(0.04, 0.15);
  h.floor_grey = uniform(0.06, 0.2);
  // light strips along x or y: rows, each cut into lamps
  h.strips_along_x = uniform(0, 1) < 0.5;
  h.strip_rows = static_cast<int>(uniform(3, 9));
  h.strip_width = uniform(0.12, 0.4);
  h.lamp_length = uniform(1.2, 3.0);
  h.lamp_gap = uniform(0.2, 2.5);
  h.strip_offset = uniform(-0.5, 0.5);
  h.lamp_phase = uniform(0, 1);
  h.lamp_radiance = uniform(8, 25);
  h.lamp_tint = Eigen::Vector3d(uniform(0.92, 1.05), 1, uniform(0.85, 1.1));
  // windows: a band of panes on the walls, daylight
  h.window_bottom = uniform(2.5, 4.0) - h.floor;
  h.window_top = h.window_bottom + uniform(0.8, 2.0);
  h.window_radiance = uniform(0.8, 4.0);
  h.pane_period = uniform(1.5, 4.0);
  h.windows_on_x_walls = uniform(0, 1) < 0.5;
  return h;
}

}  // namespace

EnvironmentMap MakeHallEnvironment(uint64_t variant, int height) {
  if (height < 8) {
    throw std::invalid_argument("MakeHallEnvironment: height " + std::to_string(height) +
                                " is below 8");
  }
  // the hall of this variant: the bin stands at the origin on a table 0.9 m above the floor
  const Hall hall = DrawHall(variant);
  const auto radiance = [&hall](const Eigen::Vector3d& d) { return hall.Radiance(d); };

  // 2 x 2 samples per pixel, so the strips' edges are smooth; rows in parallel
  EnvironmentMap out;
  out.name = "hall " + std::to_string(variant);
  out.radiance.create(height, 2 * height, CV_32FC3);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < 2 * height; ++u) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (const double du : {-0.25, 0.25}) {
          for (const double dv : {-0.25, 0.25}) {
            sum += radiance(DirectionOfPixel(u + du, v + dv, 2 * height, height));
          }
        }
        const Eigen::Vector3f mean = (sum / 4).cast<float>();
        out.radiance.at<cv::Vec3f>(v, u) = cv::Vec3f(mean.x(), mean.y(), mean.z());
      }
    }
  });
  return out;
}

namespace {

// Irradiance from the radiance pyramid: the radiance (at 64 x 32, or the base when smaller)
// projected on the first 9 spherical harmonics, with the cosine lobe applied (pi, 2 pi / 3,
// pi / 4 per band) and divided by pi.
std::array<Eigen::Vector3f, 9> IrradianceSh(const std::vector<cv::Mat>& pyramid) {
  size_t coarse_level = 0;
  while (coarse_level + 1 < pyramid.size() && pyramid[coarse_level + 1].rows >= 32) ++coarse_level;
  const cv::Mat& coarse = pyramid[coarse_level];
  std::array<Eigen::Vector3d, 9> sh;
  sh.fill(Eigen::Vector3d::Zero());
  for (int v = 0; v < coarse.rows; ++v) {
    const double theta = kPi * (v + 0.5) / coarse.rows;
    const double solid_angle = (2 * kPi / coarse.cols) * (kPi / coarse.rows) * std::sin(theta);
    for (int u = 0; u < coarse.cols; ++u) {
      const cv::Vec3f& c = coarse.at<cv::Vec3f>(v, u);
      const Eigen::Vector3d radiance(c[0], c[1], c[2]);
      const std::array<double, 9> basis = ShBasis(DirectionOfPixel(u, v, coarse.cols, coarse.rows));
      for (int i = 0; i < 9; ++i) sh[i] += radiance * (basis[i] * solid_angle);
    }
  }
  std::array<Eigen::Vector3f, 9> irradiance;
  const double band_factor[3] = {1.0, 2.0 / 3.0, 1.0 / 4.0};
  for (int i = 0; i < 9; ++i) {
    const int band = i == 0 ? 0 : (i < 4 ? 1 : 2);
    irradiance[i] = (sh[i] * band_factor[band]).cast<float>();
  }
  return irradiance;
}

}  // namespace

PrefilteredEnvironment Prefilter(const EnvironmentMap& environment, int base_width) {
  constexpr int kLevels = PrefilteredEnvironment::kLevels;
  if (environment.radiance.empty() || environment.radiance.type() != CV_32FC3) {
    throw std::invalid_argument("Prefilter: environment '" + environment.name +
                                "' is not a non-empty CV_32FC3 image");
  }
  if (base_width <= 0 || base_width % (1 << kLevels) != 0) {
    throw std::invalid_argument("Prefilter: base_width " + std::to_string(base_width) +
                                " is not a positive multiple of " + std::to_string(1 << kLevels));
  }
  PrefilteredEnvironment out;
  out.name = environment.name;

  // the radiance at the base size, and a pyramid of it to sample from
  const cv::Mat base = Resample(environment.radiance, base_width);
  std::vector<cv::Mat> pyramid = {base};
  while (pyramid.back().rows > 1) {
    cv::Mat half;
    cv::resize(pyramid.back(), half, cv::Size(pyramid.back().cols / 2, pyramid.back().rows / 2), 0,
               0, cv::INTER_AREA);
    pyramid.push_back(half);
  }
  const double texel_solid_angle = 4 * kPi / (static_cast<double>(base.cols) * base.rows);

  // level 0 as it is; level k: the GGX lobe of roughness k / (n - 1) with n = v = r, each sample
  // read from the pyramid level whose texels match its share of the lobe
  out.levels.push_back(base);
  constexpr uint32_t kSamples = 64;
  struct LobeSample {
    Eigen::Vector3d h_local;  // the half vector in the frame around the normal
    double lod;               // the pyramid level to read it from
  };
  std::array<LobeSample, kSamples> lobe;
  for (int k = 1; k < kLevels; ++k) {
    const double roughness = static_cast<double>(k) / (kLevels - 1);
    const double alpha = roughness * roughness;
    // the lobe's samples, the same in every texel's frame
    for (uint32_t i = 0; i < kSamples; ++i) {
      lobe[i].h_local = SampleGgx(Hammersley(i, kSamples), alpha);
      const double n_dot_h = lobe[i].h_local.z();
      // pdf of l with n = v: D / 4; the sample's solid angle against a base texel's
      const double pdf = DistributionGgx(n_dot_h, alpha) / 4;
      const double sample_solid_angle = 1 / (kSamples * pdf + 1e-12);
      lobe[i].lod = 0.5 * std::log2(sample_solid_angle / texel_solid_angle) + 1;
    }
    cv::Mat level(base.rows >> k, base.cols >> k, CV_32FC3);
    // rows in parallel: each texel is a pure function of the pyramid
    cv::parallel_for_(cv::Range(0, level.rows), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        for (int u = 0; u < level.cols; ++u) {
          const Eigen::Vector3d n = DirectionOfPixel(u, v, level.cols, level.rows);
          const Eigen::Matrix3d frame = FrameAround(n);
          Eigen::Vector3f sum = Eigen::Vector3f::Zero();
          double weight = 0;
          for (const LobeSample& sample : lobe) {
            const Eigen::Vector3d h = frame * sample.h_local;
            const Eigen::Vector3d l = 2 * n.dot(h) * h - n;
            const double n_dot_l = n.dot(l);
            if (n_dot_l <= 0) continue;
            sum += static_cast<float>(n_dot_l) * SampleLod(pyramid, l, sample.lod);
            weight += n_dot_l;
          }
          const Eigen::Vector3f mean = sum / static_cast<float>(weight);
          level.at<cv::Vec3f>(v, u) = cv::Vec3f(mean.x(), mean.y(), mean.z());
        }
      }
    });
    out.levels.push_back(level);
  }

  // irradiance: the radiance's spherical harmonics with the cosine lobe applied
  out.irradiance_sh = IrradianceSh(pyramid);
  return out;
}

Eigen::Vector3d DirectionOfOctahedral(double s, double t) {
  const double px = 2 * s - 1;
  const double py = 2 * t - 1;
  Eigen::Vector3d d(px, py, 1 - std::abs(px) - std::abs(py));
  if (d.z() < 0) {
    d.x() = (1 - std::abs(py)) * (px >= 0 ? 1 : -1);
    d.y() = (1 - std::abs(px)) * (py >= 0 ? 1 : -1);
  }
  return d.normalized();
}

cv::Mat OctahedralOf(const cv::Mat& equirectangular, int size) {
  if (equirectangular.empty() || equirectangular.type() != CV_32FC3 || size <= 0) {
    throw std::invalid_argument("OctahedralOf: need a non-empty CV_32FC3 image and size > 0");
  }
  cv::Mat out(size, size, CV_32FC3);
  // rows in parallel: each texel is a pure function of the image
  cv::parallel_for_(cv::Range(0, size), [&](const cv::Range& rows) {
    for (int row = rows.start; row < rows.end; ++row) {
      for (int column = 0; column < size; ++column) {
        const Eigen::Vector3f c = SampleBilinear(
            equirectangular, DirectionOfOctahedral((column + 0.5) / size, (row + 0.5) / size));
        out.at<cv::Vec3f>(row, column) = cv::Vec3f(c.x(), c.y(), c.z());
      }
    }
  });
  return out;
}

Eigen::Vector3f EvaluateIrradianceSh(const std::array<Eigen::Vector3f, 9>& sh,
                                     const Eigen::Vector3d& n) {
  const std::array<double, 9> basis = ShBasis(n.normalized());
  Eigen::Vector3f sum = Eigen::Vector3f::Zero();
  for (int i = 0; i < 9; ++i) sum += sh[i] * static_cast<float>(basis[i]);
  return sum.cwiseMax(0.f);
}

cv::Mat ComputeDfgLut(int size, int samples) {
  if (size <= 0 || samples <= 0) {
    throw std::invalid_argument("ComputeDfgLut: size and samples must be positive");
  }
  cv::Mat lut(size, size, CV_32FC2);
  for (int j = 0; j < size; ++j) {
    const double roughness = (j + 0.5) / size;
    const double alpha = roughness * roughness;
    for (int i = 0; i < size; ++i) {
      const double n_dot_v = (i + 0.5) / size;
      const Eigen::Vector3d view(std::sqrt(1 - n_dot_v * n_dot_v), 0, n_dot_v);
      // importance-sampled: f n.l / pdf = 4 V n.l v.h / n.h, split by Schlick's Fresnel
      double fresnel_peak = 0;
      double total = 0;
      for (int s = 0; s < samples; ++s) {
        const Eigen::Vector3d h = SampleGgx(Hammersley(s, samples), alpha);
        const double v_dot_h = view.dot(h);
        const Eigen::Vector3d l = 2 * v_dot_h * h - view;
        const double n_dot_l = l.z();
        if (n_dot_l <= 0 || v_dot_h <= 0) continue;
        const double g =
            4 * VisibilitySmithGgxCorrelated(n_dot_v, n_dot_l, alpha) * n_dot_l * v_dot_h / h.z();
        const double fc = std::pow(1 - v_dot_h, 5);
        fresnel_peak += g * fc;
        total += g;
      }
      lut.at<cv::Vec2f>(j, i) = cv::Vec2f(static_cast<float>(fresnel_peak / samples),
                                          static_cast<float>(total / samples));
    }
  }
  return lut;
}

}  // namespace stackgen
