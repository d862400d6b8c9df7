#include "consumers/view/contact_sheet.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <system_error>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "contract/rle.h"
#include "contract/scene_contract.h"

namespace stackgen {
namespace sheet {
namespace {

// bus scenes: at most this many instances, and this many bytes of decoded masks
constexpr int kMaxInstances = 999;
constexpr int64_t kMaxMaskBytes = int64_t{1} << 30;


namespace fs = std::filesystem;

// the largest sheet drawn, pixels (about 0.8 GB of BGR)
constexpr int64_t kMaxSheetPixels = int64_t{1} << 28;

// objects whose visible pixels are under this fraction of the image also show visib_fract
constexpr double kSmallObjectFraction = 0.015;

// outline colours (BGR): annotated green, ignored orange, dropped gray; see PrintHelp
const cv::Scalar kAnnotatedColour(0, 230, 0);
const cv::Scalar kIgnoredColour(0, 150, 255);
const cv::Scalar kDroppedColour(160, 160, 160);
const cv::Scalar kBackground(40, 40, 40);
const cv::Scalar kTextColour(235, 235, 235);

cv::Scalar ColourOf(Label label) {
  switch (label) {
    case Label::kAnnotated:
      return kAnnotatedColour;
    case Label::kIgnored:
      return kIgnoredColour;
    case Label::kDropped:
      break;
  }
  return kDroppedColour;
}

// ".24" for 0.24, "1.00" for 1
std::string FractionText(double fraction) {
  char text[16];
  std::snprintf(text, sizeof(text), "%.2f", fraction);
  std::string result = text;
  if (result.rfind("0.", 0) == 0) result.erase(0, 1);
  return result;
}

// text with a dark rim, so it reads on any image
void PutLabel(cv::Mat& image, const std::string& text, cv::Point origin, const cv::Scalar& colour,
              double scale) {
  cv::putText(image, text, origin, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(0, 0, 0), 3,
              cv::LINE_AA);
  cv::putText(image, text, origin, cv::FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv::LINE_AA);
}

// the legend: the colours and what a label means (BOP: by visib_fract, a gt id)
void DrawLegend(cv::Mat& sheet, bool bop) {
  struct Item {
    const char* text;
    cv::Scalar colour;
    int thickness;
  };
  const std::vector<Item> items =
      bop ? std::vector<Item>{{"ann: visib_fract >= 0.3", kAnnotatedColour, 2},
                              {"ign: visib_fract < 0.3", kIgnoredColour, 2}}
          : std::vector<Item>{{"ann: annotated (iscrowd 0)", kAnnotatedColour, 2},
                              {"ign: ignored (iscrowd 1)", kIgnoredColour, 2},
                              {"drop: dropped (bus only)", kDroppedColour, 1}};
  int x = kGap + 2;
  const int y = 16;
  for (const Item& item : items) {
    cv::line(sheet, cv::Point(x, y - 4), cv::Point(x + 16, y - 4), item.colour, item.thickness,
             cv::LINE_8);
    x += 20;
    cv::putText(sheet, item.text, cv::Point(x, y), cv::FONT_HERSHEY_SIMPLEX, 0.4, kTextColour, 1,
                cv::LINE_AA);
    int baseline = 0;
    x += cv::getTextSize(item.text, cv::FONT_HERSHEY_SIMPLEX, 0.4, 1, &baseline).width + 14;
  }
  cv::putText(sheet,
              std::string("label: ") + (bop ? "gt id" : "instance id") +
                  "; \"7 .24\": visib_fract, shown under 1.5% of image visible",
              cv::Point(kGap + 2, 36), cv::FONT_HERSHEY_SIMPLEX, 0.4, kTextColour, 1, cv::LINE_AA);
}

}  // namespace

cv::Mat RleMask(const std::string& counts, int height, int width) {
  if (height < 0 || width < 0) {
    throw std::runtime_error("negative mask size " + std::to_string(height) + " x " +
                             std::to_string(width));
  }
  cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
  DecodeRleInto(counts, height, width, mask.data);
  mask *= 255;
  return mask;
}

// "ann", "ign", "drop" counts; the dropped count only where it is known
std::string CountsText(const std::vector<InstanceView>& instances, bool dropped_known) {
  int annotated = 0, ignored = 0, dropped = 0;
  for (const InstanceView& instance : instances) {
    if (instance.label == Label::kAnnotated) ++annotated;
    if (instance.label == Label::kIgnored) ++ignored;
    if (instance.label == Label::kDropped) ++dropped;
  }
  std::string text = std::to_string(annotated) + " ann, " + std::to_string(ignored) + " ign";
  if (dropped_known) text += ", " + std::to_string(dropped) + " drop";
  return text;
}

// the scene's image scaled to `tile_width`, its instances outlined and labelled
cv::Mat RenderTile(const SceneView& scene, int tile_width) {
  const double scale = static_cast<double>(tile_width) / scene.image.cols;
  const double tile_height = scene.image.rows * scale;
  // a very tall image would make a huge tile: refuse before allocating it
  if (tile_height * tile_width > static_cast<double>(kMaxSheetPixels)) {
    throw std::runtime_error("a " + std::to_string(scene.image.cols) + " x " +
                             std::to_string(scene.image.rows) + " image scaled to " +
                             std::to_string(tile_width) + " px wide makes a tile over " +
                             std::to_string(kMaxSheetPixels) + " pixels");
  }
  const cv::Size size(tile_width, std::max(1, static_cast<int>(std::lround(tile_height))));
  const bool shrink = scale < 1.0;
  cv::Mat tile;
  cv::resize(scene.image, tile, size, 0, 0, shrink ? cv::INTER_AREA : cv::INTER_NEAREST);
  const double image_area = static_cast<double>(scene.image.total());

  // outlines: dropped first, annotated last (on top)
  std::vector<const InstanceView*> order;
  for (const InstanceView& instance : scene.instances) order.push_back(&instance);
  std::stable_sort(order.begin(), order.end(), [](const InstanceView* a, const InstanceView* b) {
    return static_cast<int>(a->label) > static_cast<int>(b->label);
  });
  struct Text {
    std::string text;
    cv::Point origin;
    cv::Scalar colour;
  };
  std::vector<Text> texts;
  for (const InstanceView* instance : order) {
    // the mask at tile size: any covered pixel counts when shrinking, so small objects stay
    cv::Mat mask;
    cv::resize(instance->mask, mask, size, 0, 0, shrink ? cv::INTER_AREA : cv::INTER_NEAREST);
    cv::threshold(mask, mask, 0, 255, cv::THRESH_BINARY);
    std::vector<std::vector<cv::Point>> contours;
    cv::findContours(mask, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
    const cv::Scalar colour = ColourOf(instance->label);
    cv::drawContours(tile, contours, -1, colour, instance->label == Label::kDropped ? 1 : 2,
                     cv::LINE_8);

    // the id at the mask's centre; small objects also get visib_fract, beside the mask
    const cv::Rect box = cv::boundingRect(mask);
    if (box.area() == 0) continue;
    const int visible = cv::countNonZero(instance->mask);
    const bool small = visible < kSmallObjectFraction * image_area;
    std::string text = std::to_string(instance->instance_id);
    if (small && std::isfinite(instance->visib_fract)) {
      text += " " + FractionText(instance->visib_fract);
    }
    int baseline = 0;
    const cv::Size text_size = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, 0.4, 1, &baseline);
    cv::Point origin =
        small ? cv::Point(box.br().x + 2, box.y + box.height / 2 + text_size.height / 2)
              : cv::Point(box.x + box.width / 2 - text_size.width / 2,
                          box.y + box.height / 2 + text_size.height / 2);
    origin.x = std::clamp(origin.x, 1, std::max(1, size.width - text_size.width - 1));
    origin.y =
        std::clamp(origin.y, text_size.height + 1, std::max(text_size.height + 1, size.height - 2));
    texts.push_back({text, origin, colour});
  }
  // texts over all outlines
  for (const Text& text : texts) PutLabel(tile, text.text, text.origin, text.colour, 0.4);
  return tile;
}

// the tiles in a grid under the legend (see PrintHelp for the layout)
cv::Mat ComposeSheet(const std::vector<Tile>& tiles, int max_columns, int tile_width, bool bop) {
  const int columns = std::min<int>(max_columns, static_cast<int>(tiles.size()));
  const int rows = (static_cast<int>(tiles.size()) + columns - 1) / columns;
  int tile_height = 1;
  for (const Tile& tile : tiles) tile_height = std::max(tile_height, tile.pixels.rows);
  const int64_t width = kGap + int64_t{columns} * (tile_width + kGap);
  const int64_t height =
      kLegendHeight + kGap + int64_t{rows} * (tile_height + kCaptionHeight + kGap);
  if (width * height > kMaxSheetPixels) {
    throw std::runtime_error("--count, --columns and --tile-width give a sheet of " +
                             std::to_string(width) + " x " + std::to_string(height) +
                             " px, more than " + std::to_string(kMaxSheetPixels) + " pixels");
  }
  cv::Mat sheet(static_cast<int>(height), static_cast<int>(width), CV_8UC3, kBackground);
  DrawLegend(sheet, bop);
  for (size_t k = 0; k < tiles.size(); ++k) {
    const int column = static_cast<int>(k) % columns;
    const int row = static_cast<int>(k) / columns;
    const int x = kGap + column * (tile_width + kGap);
    const int y = kLegendHeight + kGap + row * (tile_height + kCaptionHeight + kGap);
    tiles[k].pixels.copyTo(sheet(cv::Rect(x, y, tile_width, tiles[k].pixels.rows)));
    // the caption, clipped to its cell
    cv::Mat caption = sheet(cv::Rect(x, y + tile_height, tile_width, kCaptionHeight));
    cv::putText(caption, tiles[k].caption, cv::Point(2, 14), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                kTextColour, 1, cv::LINE_AA);
  }
  return sheet;
}

// encodes `sheet` as PNG into `path` through `path`.tmp and a rename
void WritePng(const cv::Mat& sheet, const std::string& path) {
  std::vector<uint8_t> png;
  if (!cv::imencode(".png", sheet, png)) throw std::runtime_error(path + ": cannot encode PNG");
  const std::string temporary = path + ".tmp";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
    out.close();
    if (!out) {
      std::error_code ignored;
      fs::remove(temporary, ignored);
      throw std::runtime_error("--out " + path + ": cannot write " + temporary);
    }
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error) {
    fs::remove(temporary, error);
    throw std::runtime_error("--out " + path + ": cannot rename " + temporary + ": " +
                             error.message());
  }
}

SceneView ViewOfMessage(const scene& message) {
  // the contract every consumer checks (contract/scene_contract.h): sizes, encodings and file
  // headers, instances, masks and their pixel counts
  std::string why;
  if (!CheckScene(message, &why)) throw std::runtime_error(why);
  const int width = message.camera.width;
  const int height = message.camera.height;
  if (width > 8192 || height > 8192) {
    throw std::runtime_error("camera.width x camera.height " + std::to_string(width) + " x " +
                             std::to_string(height) + " outside 1..8192");
  }
  // the colour image
  const image& color = message.color;
  SceneView scene;
  const bool rgb = color.pixel_format == image::PIXEL_RGB8;
  if (color.encoding == image::ENCODING_RAW) {
    const cv::Mat pixels(height, width, rgb ? CV_8UC3 : CV_8UC1,
                         const_cast<uint8_t*>(color.data.data()));
    cv::cvtColor(pixels, scene.image, rgb ? cv::COLOR_RGB2BGR : cv::COLOR_GRAY2BGR);
  } else {
    // PNG or JPEG, whose header CheckScene found to declare the camera's size
    scene.image = cv::imdecode(color.data, cv::IMREAD_COLOR);
    if (scene.image.empty()) throw std::runtime_error("color.data does not decode");
    if (scene.image.cols != width || scene.image.rows != height) {
      throw std::runtime_error("color.data holds a " + std::to_string(scene.image.cols) + " x " +
                               std::to_string(scene.image.rows) + " image, the camera is " +
                               std::to_string(width) + " x " + std::to_string(height));
    }
  }

  // each instance's mask is decoded at full size: bound what that may take
  if (message.num_instances > kMaxInstances ||
      static_cast<int64_t>(message.num_instances) * width * height > kMaxMaskBytes) {
    throw std::runtime_error("num_instances " + std::to_string(message.num_instances) + " of " +
                             std::to_string(width) + " x " + std::to_string(height) +
                             " masks exceeds the limit (at most " + std::to_string(kMaxInstances) +
                             " instances and " + std::to_string(kMaxMaskBytes >> 20) +
                             " MiB of masks)");
  }
  for (size_t k = 0; k < message.instances.size(); ++k) {
    const instance& instance = message.instances[k];
    const std::string field = "instances[" + std::to_string(k) + "]";
    InstanceView view;
    try {
      view.mask = RleMask(instance.mask_visib_rle, height, width);
    } catch (const std::exception& error) {
      throw std::runtime_error(field + ".mask_visib_rle: " + error.what());
    }
    if (instance.px_count_visib == 0) continue;  // nothing to outline
    view.label = instance.annotated ? Label::kAnnotated
                 : instance.ignored ? Label::kIgnored
                                    : Label::kDropped;
    view.instance_id = instance.instance_id;
    view.visib_fract = instance.visib_fract;
    scene.instances.push_back(std::move(view));
  }
  scene.caption = "scene " + std::to_string(message.header.generator_id) + "/" +
                  std::to_string(message.header.seq) + ": " + CountsText(scene.instances, true);
  return scene;
}

}  // namespace sheet
}  // namespace stackgen
