#include "gen/randomize/background.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <system_error>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "gen/randomize/uniform.h"

namespace stackgen {
namespace {

using Kind = config::BackgroundConfig::Kind;

constexpr double kPi = 3.14159265358979323846;

// shifts stripe and square coordinates positive, so truncation is floor; even, so parity holds.
constexpr double kPositiveOffset = 1 << 20;

// one colour, each channel uniform in [min, max] display units, as 0..255.
cv::Vec3b DrawColour(double min, double max, std::mt19937_64& rng) {
  cv::Vec3b colour;
  for (int c = 0; c < 3; ++c) colour[c] = cv::saturate_cast<uchar>(Uniform(rng, min, max) * 255);
  return colour;
}

// `path` decoded as CV_8UC3 RGB; empty when OpenCV cannot read it.
cv::Mat ReadRgb(const std::string& path) {
  cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR);
  if (bgr.empty()) return bgr;
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  return rgb;
}

// fills `image` with colours[parity(x, y)], rows in parallel; `parity` must be thread-safe.
template <typename Parity>
void FillTwoColours(cv::Mat* image, const cv::Vec3b colours[2], const Parity& parity) {
  cv::parallel_for_(cv::Range(0, image->rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      auto* row = image->ptr<cv::Vec3b>(y);
      for (int x = 0; x < image->cols; ++x) row[x] = colours[parity(x, y)];
    }
  });
}

cv::Mat DrawStripes(int width, int height, const cv::Vec3b colours[2], std::mt19937_64& rng) {
  const double period = Uniform(rng, 8.0, std::max(8.0, width / 4.0));
  const double angle = Uniform(rng, 0.0, kPi);
  const double phase = Uniform01(rng);
  // stripe index along the stripes' normal, in half periods.
  const double along_x = std::cos(angle) / (period / 2);
  const double along_y = std::sin(angle) / (period / 2);
  const double start = kPositiveOffset + 2 * phase;
  cv::Mat image(height, width, CV_8UC3);
  FillTwoColours(&image, colours, [&](int x, int y) {
    return static_cast<int64_t>(start + x * along_x + y * along_y) & 1;
  });
  return image;
}

cv::Mat DrawChecker(int width, int height, const cv::Vec3b colours[2], std::mt19937_64& rng) {
  const double side = Uniform(rng, 8.0, std::max(8.0, std::min(width, height) / 4.0));
  const double angle = Uniform(rng, 0.0, kPi / 2);
  const double phase_u = Uniform(rng, 0.0, 2.0);
  const double phase_v = Uniform(rng, 0.0, 2.0);
  // square indices along the two rotated axes.
  const double cos_side = std::cos(angle) / side;
  const double sin_side = std::sin(angle) / side;
  const double start_u = kPositiveOffset + phase_u;
  const double start_v = kPositiveOffset + phase_v;
  cv::Mat image(height, width, CV_8UC3);
  FillTwoColours(&image, colours, [&](int x, int y) {
    const auto u = static_cast<int64_t>(start_u + x * cos_side + y * sin_side);
    const auto v = static_cast<int64_t>(start_v - x * sin_side + y * cos_side);
    return (u + v) & 1;
  });
  return image;
}

cv::Mat DrawNoise(int width, int height, const cv::Vec3b colours[2], std::mt19937_64& rng) {
  // work at about 256 px on the longer side: the finest octave still spans >= 4 of its pixels.
  const int longest = std::max(width, height);
  const int factor = std::clamp((longest + 255) / 256, 1, 8);
  const int low_width = (width + factor - 1) / factor;
  const int low_height = (height + factor - 1) / factor;
  const double coarsest_px = Uniform(rng, 0.25, 1.0) * longest;
  const double finest_px = std::max(8.0, longest / 64.0);
  const double persistence = Uniform(rng, 0.4, 0.65);

  // octaves: random grids of one value per cell, bicubic at a random offset, summed.
  cv::Mat sum = cv::Mat::zeros(low_height, low_width, CV_32F);
  double period_px = coarsest_px;
  double amplitude = 1;
  for (int octave = 0; octave < 6 && (octave == 0 || period_px >= finest_px); ++octave) {
    const double cell = period_px / factor;
    const int grid_width = static_cast<int>(std::ceil(low_width / cell)) + 4;
    const int grid_height = static_cast<int>(std::ceil(low_height / cell)) + 4;
    cv::Mat grid(grid_height, grid_width, CV_32F);
    for (int y = 0; y < grid_height; ++y) {
      auto* row = grid.ptr<float>(y);
      for (int x = 0; x < grid_width; ++x) row[x] = static_cast<float>(Uniform01(rng));
    }
    // low-res pixel (x, y) samples the grid at (x / cell + 1 + offset), away from its border.
    const double offset_x = 1 + Uniform01(rng);
    const double offset_y = 1 + Uniform01(rng);
    const cv::Matx23d grid_from_pixel(1 / cell, 0, offset_x, 0, 1 / cell, offset_y);
    cv::Mat layer;
    cv::warpAffine(grid, layer, grid_from_pixel, sum.size(), cv::INTER_CUBIC | cv::WARP_INVERSE_MAP,
                   cv::BORDER_REPLICATE);
    cv::scaleAdd(layer, amplitude, sum, sum);
    period_px /= 2;
    amplitude *= persistence;
  }

  // stretch to [0, 1] and blend the two colours at low resolution.
  double lo = 0;
  double hi = 0;
  cv::minMaxLoc(sum, &lo, &hi);
  const double scale = hi > lo ? 1 / (hi - lo) : 0;
  cv::Mat low(low_height, low_width, CV_8UC3);
  for (int y = 0; y < low_height; ++y) {
    const auto* in = sum.ptr<float>(y);
    auto* out = low.ptr<cv::Vec3b>(y);
    for (int x = 0; x < low_width; ++x) {
      const double t = (in[x] - lo) * scale;
      for (int c = 0; c < 3; ++c) {
        out[x][c] = cv::saturate_cast<uchar>(colours[0][c] + t * (colours[1][c] - colours[0][c]));
      }
    }
  }
  if (factor == 1) return low;

  // upsample to the frame.
  cv::Mat image;
  cv::resize(low, image, cv::Size(width, height), 0, 0, cv::INTER_CUBIC);
  return image;
}

}  // namespace

BackgroundSource::BackgroundSource(const config::BackgroundConfig& config,
                                   const std::string& image_dir_resolved)
    : min_(config.min()), max_(config.max()) {
  // the kinds to draw from.
  for (const int kind : config.kind()) {
    if (kind == config::BackgroundConfig::KIND_UNSPECIFIED ||
        !config::BackgroundConfig::Kind_IsValid(kind)) {
      throw std::runtime_error("background.kind: KIND_UNSPECIFIED (or an unknown value " +
                               std::to_string(kind) +
                               ") is not a background; list PLAIN, NOISE, STRIPES, CHECKER or "
                               "IMAGE");
    }
    kinds_.push_back(static_cast<Kind>(kind));
  }
  if (kinds_.empty()) {
    kinds_ = {config::BackgroundConfig::PLAIN, config::BackgroundConfig::NOISE,
              config::BackgroundConfig::STRIPES, config::BackgroundConfig::CHECKER};
    if (!config.image_dir().empty()) kinds_.push_back(config::BackgroundConfig::IMAGE);
  }
  if (std::find(kinds_.begin(), kinds_.end(), config::BackgroundConfig::IMAGE) == kinds_.end()) {
    return;
  }

  // list the folder, sorted by file name.
  namespace fs = std::filesystem;
  const std::string where = "background.image_dir: folder '" + image_dir_resolved + "'";
  if (image_dir_resolved.empty()) {
    throw std::runtime_error(
        "background.image_dir is empty but background.kind lists IMAGE; set it to a folder of "
        "images");
  }
  std::error_code error;
  if (!fs::is_directory(image_dir_resolved, error)) {
    throw std::runtime_error(
        where + (fs::exists(image_dir_resolved, error) ? " is not a folder" : " does not exist"));
  }
  std::vector<fs::path> files;
  fs::directory_iterator entry(image_dir_resolved, error);
  for (; !error && entry != fs::directory_iterator(); entry.increment(error)) {
    // a broken link or an entry that vanished is skipped like an unreadable file.
    std::error_code ignored;
    if (entry->is_regular_file(ignored)) files.push_back(entry->path());
  }
  if (error) throw std::runtime_error(where + " cannot be listed: " + error.message());
  std::sort(files.begin(), files.end(),
            [](const fs::path& a, const fs::path& b) { return a.filename() < b.filename(); });

  // keep the readable images, decoded while the cache budget lasts.
  size_t cached_bytes = 0;
  for (const fs::path& file : files) {
    cv::Mat rgb = ReadRgb(file.string());
    if (rgb.empty()) continue;
    const size_t bytes = rgb.total() * rgb.elemSize();
    if (cached_bytes + bytes <= kImageCacheBytes) {
      cached_bytes += bytes;
    } else {
      rgb.release();
    }
    images_.push_back({file.string(), rgb});
  }
  if (images_.empty()) {
    throw std::runtime_error(where + " holds no image OpenCV can read (" +
                             std::to_string(files.size()) +
                             " files tried; PNG, JPEG, BMP, TIFF, ... are read)");
  }
}

std::vector<std::string> BackgroundSource::image_paths() const {
  std::vector<std::string> paths;
  for (const Image& image : images_) paths.push_back(image.path);
  return paths;
}

cv::Mat BackgroundSource::Draw(int width, int height, std::mt19937_64& engine,
                               config::BackgroundConfig::Kind* kind) const {
  if (width <= 0 || height <= 0) {
    throw std::runtime_error("BackgroundSource::Draw: image size " + std::to_string(width) + " x " +
                             std::to_string(height) + " is not positive");
  }
  // two draws from the scene's engine: the kind, and a seed for its parameters.
  const Kind drawn = kinds_[UniformIndex(engine, static_cast<int>(kinds_.size()))];
  std::mt19937_64 rng(engine());
  if (kind != nullptr) *kind = drawn;

  // the colours first, so every kind starts alike.
  const cv::Vec3b colours[2] = {DrawColour(min_, max_, rng), DrawColour(min_, max_, rng)};
  switch (drawn) {
    case config::BackgroundConfig::NOISE:
      return DrawNoise(width, height, colours, rng);
    case config::BackgroundConfig::STRIPES:
      return DrawStripes(width, height, colours, rng);
    case config::BackgroundConfig::CHECKER:
      return DrawChecker(width, height, colours, rng);
    case config::BackgroundConfig::IMAGE:
      break;
    default:
      return cv::Mat(height, width, CV_8UC3,
                     cv::Scalar(colours[0][0], colours[0][1], colours[0][2]));
  }

  // IMAGE: pick a file, crop the part that covers the frame at a random place, scale it.
  const Image& chosen = images_[UniformIndex(rng, static_cast<int>(images_.size()))];
  const cv::Mat source = chosen.rgb.empty() ? ReadRgb(chosen.path) : chosen.rgb;
  if (source.empty()) {
    throw std::runtime_error("background.image_dir: image '" + chosen.path +
                             "' could be read when listed but no longer can");
  }
  const double scale =
      std::max(static_cast<double>(width) / source.cols, static_cast<double>(height) / source.rows);
  const int crop_width = std::clamp(static_cast<int>(std::ceil(width / scale)), 1, source.cols);
  const int crop_height = std::clamp(static_cast<int>(std::ceil(height / scale)), 1, source.rows);
  const int crop_x = UniformIndex(rng, source.cols - crop_width + 1);
  const int crop_y = UniformIndex(rng, source.rows - crop_height + 1);
  cv::Mat crop = source(cv::Rect(crop_x, crop_y, crop_width, crop_height));
  // shrink by the integer part of the factor with a box filter (OpenCV's fast path needs sizes
  // divisible by it; the trim is under one output pixel), then bilinear to the exact size.
  const int box = static_cast<int>(1 / scale);
  if (box >= 2) {
    const cv::Rect divisible(0, 0, crop.cols / box * box, crop.rows / box * box);
    cv::Mat shrunk;
    cv::resize(crop(divisible), shrunk, divisible.size() / box, 0, 0, cv::INTER_AREA);
    crop = shrunk;
  }
  cv::Mat image;
  cv::resize(crop, image, cv::Size(width, height), 0, 0, cv::INTER_LINEAR);
  return image;
}

}  // namespace stackgen
