#pragma once

#include <cstddef>
#include <random>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stackgen_config.pb.h"

namespace stackgen {

/// Makes per-scene backgrounds (CV_8UC3, RGB order) following BackgroundConfig. Draw is const and
/// touches no shared state, so one source may serve several threads.
class BackgroundSource {
 public:
  /// Decoded images kept in memory; images past this budget (in file-name order) are read from
  /// disk again at each draw that picks them.
  static constexpr size_t kImageCacheBytes = size_t{256} << 20;

  /// Kinds: config.kind(), or when empty the default set PLAIN, NOISE, STRIPES, CHECKER, plus
  /// IMAGE when config.image_dir() is non-empty. When the kinds include IMAGE, lists
  /// `image_dir_resolved` (config.image_dir() already resolved against the config's folder):
  /// every regular file is decoded once, those OpenCV cannot read are skipped without error, and
  /// the readable ones are kept sorted by file name so draws are reproducible. Throws
  /// std::runtime_error naming background.image_dir and the folder when the folder is missing,
  /// not a folder, or holds no readable image, and naming background.kind when it lists
  /// KIND_UNSPECIFIED.
  BackgroundSource(const config::BackgroundConfig& config, const std::string& image_dir_resolved);

  /// A width x height CV_8UC3 RGB image. Takes exactly two values from `engine` whatever the
  /// kind: the kind (uniform over kinds()), then a seed for its parameters, so what is drawn
  /// after it does not depend on the kind. Colours are display values, each channel uniform in
  /// [min, max] * 255, rounded. The kinds:
  ///  - PLAIN: one colour.
  ///  - NOISE: smooth value noise between two colours: 1..6 octaves of small random grids
  ///    upsampled with bicubic interpolation and summed (coarsest period 1/4..1 of the longer
  ///    side, halving down to max(8 px, longer side / 64), amplitude falling by 0.4..0.65 per
  ///    octave), stretched to the full range between the colours, computed at about 256 px on
  ///    the longer side and upsampled bicubically to width x height.
  ///  - STRIPES: stripes of two colours, one period (a stripe of each) uniform in
  ///    [8, max(8, width / 4)] px, angle uniform in [0, 180) degrees, random phase; edges are
  ///    not antialiased, so the image holds exactly the two colours.
  ///  - CHECKER: a checkerboard of two colours, square side uniform in
  ///    [8, max(8, min(width, height) / 4)] px, angle uniform in [0, 90) degrees, random phase;
  ///    not antialiased (exactly the two colours).
  ///  - IMAGE: a file of image_paths() drawn uniformly, scaled (aspect ratio kept) to cover
  ///    width x height and cropped at a random position: the covering crop is shrunk by the
  ///    integer part of the shrink factor with a box filter, then resized bilinearly.
  /// Sets *kind to the kind drawn when not null. Throws std::runtime_error when width or height
  /// is not positive, or when an image past the cache budget can no longer be read.
  cv::Mat Draw(int width, int height, std::mt19937_64& engine,
               config::BackgroundConfig::Kind* kind = nullptr) const;

  /// The kinds Draw picks from, in order.
  const std::vector<config::BackgroundConfig::Kind>& kinds() const { return kinds_; }

  /// The readable images of image_dir, sorted by file name (empty without IMAGE).
  std::vector<std::string> image_paths() const;

 private:
  struct Image {
    std::string path;
    cv::Mat rgb;  // CV_8UC3; empty when past the cache budget
  };

  double min_ = 0;
  double max_ = 1;
  std::vector<config::BackgroundConfig::Kind> kinds_;
  std::vector<Image> images_;
};

}  // namespace stackgen
