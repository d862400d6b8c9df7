#pragma once

// The contact sheet of stackgen-view and stackgen-monitor: each scene's image with its
// instances' visible masks outlined in the colour of their label, the tiles in a grid under a
// legend, written as one PNG.

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <stackgen/scene.hpp>

namespace stackgen {
namespace sheet {

// the sheet: a legend on top, then rows of cells (the tile over its caption), kGap apart
inline constexpr int kLegendHeight = 44;
inline constexpr int kCaptionHeight = 20;
inline constexpr int kGap = 4;
// the widest sheet drawn
inline constexpr int64_t kMaxSheetWidth = 32000;

// how an instance is labelled, as the colour of its outline says
enum class Label { kAnnotated, kIgnored, kDropped };

// one instance to outline
struct InstanceView {
  cv::Mat mask;  // CV_8UC1 of the image's size, nonzero = visible
  Label label = Label::kAnnotated;
  int64_t instance_id = 0;
  double visib_fract = std::numeric_limits<double>::quiet_NaN();  // NaN: unknown
};

// one scene to draw
struct SceneView {
  cv::Mat image;  // CV_8UC3, BGR
  std::vector<InstanceView> instances;
  std::string caption;
};

// a drawn tile and the caption under it
struct Tile {
  cv::Mat pixels;
  std::string caption;
};

/// The mask (CV_8UC1, 255 inside) of a compressed COCO RLE string over height x width pixels
/// (contract/rle.h's decoder; throws as it does, naming what is wrong).
cv::Mat RleMask(const std::string& counts, int height, int width);

/// A scene message as a SceneView: its colour image (BGR), every instance with visible pixels
/// outlined by its label, the caption "scene GENERATOR/SEQ: counts". Throws std::runtime_error
/// naming the field when the scene breaks the contract (contract/scene_contract.h) or its masks
/// would take more than 1 GiB (at most 999 instances).
SceneView ViewOfMessage(const scene& message);

/// A caption's counts of the scene's instances by label ("ann", "ign" and, where the source
/// knows them, "drop").
std::string CountsText(const std::vector<InstanceView>& instances, bool dropped_known);

/// The scene's image scaled to `tile_width`, its instances' visible masks outlined in the colour
/// of their label (small ones also show their visib_fract); throws if the tile would pass 2^28
/// pixels.
cv::Mat RenderTile(const SceneView& scene, int tile_width);

/// The tiles in a grid of at most `max_columns`, each over its caption, under the legend (BOP:
/// labels by visib_fract and gt ids); throws, naming the flags, if the sheet would pass about
/// 0.8 GB (2^28 pixels).
cv::Mat ComposeSheet(const std::vector<Tile>& tiles, int max_columns, int tile_width, bool bop);

/// Encodes `sheet` as PNG into `path` through `path`.tmp and a rename; errors name --out.
void WritePng(const cv::Mat& sheet, const std::string& path);

}  // namespace sheet
}  // namespace stackgen
