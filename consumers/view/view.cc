// stackgen-view: a contact sheet (one PNG) of scenes from a COCO dataset written by stackgen-coco,
// a BOP dataset written by stackgen-bop or from STACKGEN_SCENE on the bus, each image with its
// instances' visible masks outlined in the colour of their label, for a quick look at what a
// dataset teaches.

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "cli/flags.h"
#include "consumers/bop/bop_dataset.h"
#include "consumers/view/contact_sheet.h"
#include "contract/bounded_decode.h"
#include "contract/rle.h"
#include "contract/scene_contract.h"
#include "session/consumer.h"

namespace {

using namespace stackgen::sheet;

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kProgram = "stackgen-view";

// scenes LCM keeps waiting for us while a tile is drawn (a best-effort consumer: a slow sheet
// drops scenes, it never holds up the generator)
constexpr int kQueueCapacity = 16;
// warnings printed one by one; later ones are only counted
constexpr int kMaxReportedWarnings = 10;
// generators heard for this long that all use another bus key are said (seconds)
constexpr double kKeyMismatchS = 2.0;
// the channels a generator signs with its key before its first scene: scenes and configs
const std::vector<std::string>& GeneratorChannels() {
  static const auto* const channels =
      new std::vector<std::string>{stackgen::kSceneChannel, stackgen::kConfigChannel};
  return *channels;
}

std::atomic<bool> stop_requested{false};

void RequestStop(int) { stop_requested = true; }

struct Flags {
  std::string coco_dir;  // COCO mode when not empty
  std::string bop_dir;   // BOP mode when not empty
  std::string split;     // BOP only ("": train_pbr, else the only split)
  bool bus = false;      // bus mode: --lcm-url given
  std::string lcm_url;   // the bus ("": ResolveLcmUrl's choice)
  std::string out;
  int count = 12;
  int columns = 4;
  int tile_width = 400;
  double timeout_s = 60.0;
  double fault_drop = 0;     // bus only
  std::string bus_key_file;  // bus only ("": ResolveBusKeyFile's choice)
  bool open_bus = false;     // bus only
  bool replay = false;       // bus only
};

void PrintHelp() {
  std::printf(
      "Usage: %s --coco DIR --out SHEET.png [--count N] [--columns C] [--tile-width W]\n"
      "       %s --bop DIR [--split NAME] --out SHEET.png [--count N] [--columns C]\n"
      "                    [--tile-width W]\n"
      "       %s --lcm-url URL --out SHEET.png [--count N] [--columns C] [--tile-width W]\n"
      "                    [--timeout S] [--bus-key-file FILE | --open-bus] [--replay]\n"
      "                    [--fault-drop F]\n"
      "\n"
      "Draws a contact sheet: a grid of scenes, each scene's image with the visible mask of every\n"
      "instance outlined and its instance id written on it, in the colour of its label:\n"
      "  green  (#00E600, 2 px)  annotated: a COCO annotation with iscrowd 0\n"
      "  orange (#FF9600, 2 px)  ignored: an ignore region, COCO iscrowd 1 (the generator's\n"
      "                          occlusion rule IGNORE)\n"
      "  gray   (#A0A0A0, 1 px)  dropped: visible but neither annotated nor ignored (bus only;\n"
      "                          a COCO file holds no such instances)\n"
      "A BOP dataset has no labels: each ground truth's visible mask (mask_visib/IM_GT.png) is\n"
      "outlined green when its visib_fract (scene_gt_info.json) is at least 0.3 (the generator's\n"
      "default annotation.min_visib_fract), else orange, with its gt id; ground truths with no\n"
      "visible pixel are only counted (hidden).\n"
      "Objects with less than 1.5%% of the image's pixels visible get their visible fraction\n"
      "beside the id: \"7 .24\" is instance 7, 24%% visible. Gray images are shown gray.\n"
      "\n"
      "Layout: a %d px legend on top, then rows of C cells (fewer when there are fewer scenes);\n"
      "a cell is the tile, the image scaled to W px wide keeping its aspect (all tiles as tall as\n"
      "the tallest), over a %d px caption line (image id, SCENE_ID/IM_ID (BOP) or\n"
      "generator_id/seq, then the counts: ann annotated, ign ignored, drop dropped, hidden\n"
      "(BOP)); %d px gaps between and around cells. The sheet is %d + C * (W + %d) px wide and\n"
      "%d + %d + rows * (tile height + %d + %d) px tall.\n"
      "\n"
      "Options:\n"
      "  --coco DIR       a COCO dataset folder (DIR/annotations.json, images in DIR/images/):\n"
      "                   its first N images by id.\n"
      "  --bop DIR        a BOP dataset folder (as stackgen-bop writes it): the first N images\n"
      "                   of its split, in scene id, image id order (SPLIT/SCENE_ID/rgb/IM_ID.png\n"
      "                   or .jpg, or gray/; scene_gt.json, scene_gt_info.json, mask_visib/).\n"
      "  --split NAME     --bop only: the split folder (default: train_pbr, else the only split\n"
      "                   folder there).\n"
      "  --lcm-url URL    listen on this LCM URL instead, as a best-effort consumer of %s:\n"
      "                   the first N distinct scenes received (repeats skipped; a scene that\n"
      "                   does not decode or disagrees with itself is skipped with a warning).\n"
      "                   Its counters go out on STACKGEN_STATUS every second and at the end\n"
      "                   (not when reading a file:// log).\n"
      "                   \"default\" means $STACKGEN_LCM_URL when set, else\n"
      "                   %s.\n"
      "  --out SHEET.png  the sheet to write (PNG; through SHEET.png.tmp and a rename).\n"
      "  --count N        scenes on the sheet, 1..1000 (default 12).\n"
      "  --columns C      tiles per row, 1..100 (default 4).\n"
      "  --tile-width W   tile width, pixels, 16..4096 (default 400).\n"
      "  --timeout S      bus only: seconds to wait for N scenes, > 0 (default 60). When fewer\n"
      "                   arrive the sheet shows those received; none is an error. SIGINT or\n"
      "                   SIGTERM stops the wait the same way.\n"
      "  --bus-key-file FILE  bus only: the bus key; scenes not signed with it are refused\n"
      "                   and counted (default: $STACKGEN_BUS_KEY_FILE; none: warns).\n"
      "  --fault-drop F   bus only: drop the fraction F in [0, 1) of the messages received,\n"
      "                   from a fixed seed (tests and demos; default 0).\n"
      "  --help           print this help and exit.\n"
      "A sheet may be at most 32000 px wide and 2^28 px in all.\n"
      "\n"
      "Exit status: 0 sheet written, 1 error (the line names the file, flag or URL), 2 bad\n"
      "command line.\n",
      kProgram, kProgram, kProgram, kLegendHeight, kCaptionHeight, kGap, kGap, kGap, kLegendHeight,
      kGap, kCaptionHeight, kGap, stackgen::kSceneChannel, stackgen::kDefaultLcmUrl);
}

Flags ParseFlags(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  parser.String("--coco", &flags.coco_dir, "a folder");
  parser.String("--bop", &flags.bop_dir, "a folder");
  parser.String("--split", &flags.split, "a folder name");
  parser.LcmUrl(&flags.lcm_url);
  parser.Custom("--out", [&flags](const std::string& value) {
    if (value.size() < 5 || value.substr(value.size() - 4) != ".png") {
      throw stackgen::UsageError("--out wants a file name ending in .png, got \"" + value + "\"");
    }
    flags.out = value;
  });
  parser.Require("--out");
  parser.Int("--count", &flags.count, 1, 1000);
  parser.Int("--columns", &flags.columns, 1, 100);
  parser.Int("--tile-width", &flags.tile_width, 16, 4096);
  parser.Double("--timeout", &flags.timeout_s, stackgen::Interval::OpenClosed(0, 86400));
  parser.FaultDrop(&flags.fault_drop);
  parser.BusKey(&flags.bus_key_file, &flags.open_bus);
  parser.Replay(&flags.replay);
  // the rules between flags
  const auto check = [&flags, &parser] {
    flags.bus = parser.Given("--lcm-url");
    const int modes =
        (parser.Given("--coco") ? 1 : 0) + (parser.Given("--bop") ? 1 : 0) + (flags.bus ? 1 : 0);
    if (modes != 1 || (parser.Given("--coco") && flags.coco_dir.empty()) ||
        (parser.Given("--bop") && flags.bop_dir.empty())) {
      throw stackgen::UsageError("give one of --coco DIR, --bop DIR or --lcm-url URL");
    }
    for (const char* bus_only : {"--timeout", "--fault-drop", "--bus-key-file"}) {
      if (parser.Given(bus_only) && !flags.bus) {
        throw stackgen::UsageError(std::string(bus_only) + " applies to --lcm-url only");
      }
    }
    if (parser.Given("--split") && flags.bop_dir.empty()) {
      throw stackgen::UsageError("--split applies to --bop only");
    }
    const int64_t sheet_width =
        kGap + int64_t{std::min(flags.columns, flags.count)} * (flags.tile_width + kGap);
    if (sheet_width > kMaxSheetWidth) {
      throw stackgen::UsageError("--columns and --tile-width give a sheet " +
                                 std::to_string(sheet_width) + " px wide, more than " +
                                 std::to_string(kMaxSheetWidth));
    }
  };
  parser.ParseOrExit(argc, argv, PrintHelp, check);
  return flags;
}

// --- COCO mode ---

// the mask of a COCO segmentation (compressed RLE, uncompressed RLE or polygons) over an image of
// `height` x `width`; throws std::runtime_error naming `where`
cv::Mat SegmentationMask(const json& segmentation, int height, int width,
                         const std::string& where) {
  try {
    if (segmentation.is_object()) {
      const json& size = segmentation.at("size");
      if (size != json{height, width}) {
        throw std::runtime_error("size is " + size.dump() + ", the image's height and width [" +
                                 std::to_string(height) + ", " + std::to_string(width) + "]");
      }
      const json& counts = segmentation.at("counts");
      if (counts.is_string()) return RleMask(counts.get<std::string>(), height, width);
      // (uncompressed counts: the same runs, compressed)
      return RleMask(stackgen::RunsToString(counts.get<std::vector<uint32_t>>()), height, width);
    }
    if (segmentation.is_array()) {
      cv::Mat mask = cv::Mat::zeros(height, width, CV_8UC1);
      for (const json& polygon : segmentation) {
        const std::vector<double> xy = polygon.get<std::vector<double>>();
        std::vector<std::vector<cv::Point>> points(1);
        for (size_t k = 0; k + 1 < xy.size(); k += 2) {
          points[0].emplace_back(static_cast<int>(std::lround(xy[k])),
                                 static_cast<int>(std::lround(xy[k + 1])));
        }
        if (points[0].size() >= 3) cv::fillPoly(mask, points, 255);
      }
      return mask;
    }
    throw std::runtime_error("neither RLE nor polygons");
  } catch (const json::exception& error) {
    throw std::runtime_error(where + ": " + error.what());
  } catch (const std::runtime_error& error) {
    throw std::runtime_error(where + ": " + error.what());
  }
}

// The COCO file `path` of the dataset in `dir`, with its images and annotations arrays.
json ReadCocoFile(const std::string& dir, const std::string& path) {
  std::error_code error;
  if (!fs::is_directory(dir, error)) {
    throw std::runtime_error("--coco " + dir + ": no such folder");
  }
  std::ifstream file(path);
  if (!file) throw std::runtime_error(path + ": cannot read");
  json root;
  try {
    root = json::parse(file);
  } catch (const json::exception& parse_error) {
    throw std::runtime_error(path + ": not valid JSON (" + std::string(parse_error.what()) + ")");
  }
  for (const char* field : {"images", "annotations"}) {
    if (!root.is_object() || !root.contains(field) || !root[field].is_array()) {
      throw std::runtime_error(path + ": not a COCO file (no \"" + field + "\" array)");
    }
  }

  return root;
}

// Image `id` of the COCO file `path` (its `record`) with its `annotations` outlined.
SceneView CocoScene(const std::string& dir, const std::string& path, int64_t id, const json& record,
                    const std::vector<const json*>& annotations) {
  std::error_code error;
  const std::string where = path + ": image " + std::to_string(id);
  if (!record.contains("file_name") || !record["file_name"].is_string()) {
    throw std::runtime_error(where + ": file_name is missing or not a string");
  }
  // stackgen-coco's file_name is relative to images/; other datasets' maybe to the folder
  const std::string file_name = record["file_name"].get<std::string>();
  const fs::path in_images = fs::path(dir) / "images" / file_name;
  const fs::path in_folder = fs::path(dir) / file_name;
  const bool found_in_images = fs::exists(in_images, error);
  if (!found_in_images && !fs::exists(in_folder, error)) {
    throw std::runtime_error(where + ": its image " + in_images.string() + " does not exist (nor " +
                             in_folder.string() + ")");
  }
  const fs::path image_path = found_in_images ? in_images : in_folder;
  SceneView scene;
  scene.image = cv::imread(image_path.string(), cv::IMREAD_COLOR);
  if (scene.image.empty()) {
    throw std::runtime_error(where + ": cannot read its image " + image_path.string() +
                             " (not an image OpenCV can decode, or damaged)");
  }
  if (record.value("width", scene.image.cols) != scene.image.cols ||
      record.value("height", scene.image.rows) != scene.image.rows) {
    throw std::runtime_error(where + ": width x height " + record["width"].dump() + " x " +
                             record["height"].dump() + " differs from " + image_path.string() +
                             " (" + std::to_string(scene.image.cols) + " x " +
                             std::to_string(scene.image.rows) + ")");
  }
  int index = 0;
  for (const json* annotation : annotations) {
    ++index;
    const std::string annotation_where =
        path + ": annotation " + annotation->value("id", json(nullptr)).dump();
    if (!annotation->contains("segmentation")) {
      throw std::runtime_error(annotation_where + ": no segmentation");
    }
    InstanceView instance;
    instance.mask = SegmentationMask((*annotation)["segmentation"], scene.image.rows,
                                     scene.image.cols, annotation_where + ": segmentation");
    const json iscrowd = annotation->value("iscrowd", json(0));
    instance.label =
        iscrowd.is_number() && iscrowd.get<double>() != 0 ? Label::kIgnored : Label::kAnnotated;
    const json instance_id = annotation->value("instance_id", json(index));
    instance.instance_id = instance_id.is_number_integer() ? instance_id.get<int64_t>() : index;
    const json visib_fract = annotation->value("visib_fract", json(nullptr));
    if (visib_fract.is_number()) instance.visib_fract = visib_fract.get<double>();
    scene.instances.push_back(std::move(instance));
  }
  return scene;
}

std::vector<Tile> ReadCocoTiles(const Flags& flags) {
  const std::string path = (fs::path(flags.coco_dir) / "annotations.json").string();
  const json root = ReadCocoFile(flags.coco_dir, path);

  // the first N images by id
  std::map<int64_t, const json*> images;
  for (size_t k = 0; k < root["images"].size(); ++k) {
    const json& image = root["images"][k];
    if (!image.is_object() || !image.contains("id") || !image["id"].is_number_integer()) {
      throw std::runtime_error(path + ": images[" + std::to_string(k) +
                               "].id is missing or not an integer");
    }
    images.emplace(image["id"].get<int64_t>(), &image);
  }
  std::map<int64_t, std::vector<const json*>> chosen;
  for (const auto& [id, image] : images) {
    if (static_cast<int>(chosen.size()) >= flags.count) break;
    chosen[id];
  }
  for (size_t k = 0; k < root["annotations"].size(); ++k) {
    const json& annotation = root["annotations"][k];
    if (!annotation.is_object() || !annotation.contains("image_id") ||
        !annotation["image_id"].is_number_integer()) {
      throw std::runtime_error(path + ": annotations[" + std::to_string(k) +
                               "].image_id is missing or not an integer");
    }
    const auto found = chosen.find(annotation["image_id"].get<int64_t>());
    if (found != chosen.end()) found->second.push_back(&annotation);
  }

  // one tile per image
  std::vector<Tile> tiles;
  for (const auto& [id, annotations] : chosen) {
    SceneView scene = CocoScene(flags.coco_dir, path, id, *images.at(id), annotations);
    scene.caption = "image " + std::to_string(id) + ": " + CountsText(scene.instances, false);
    tiles.push_back({RenderTile(scene, flags.tile_width), scene.caption});
  }
  std::printf("%s: %s: %zu of %zu images\n", kProgram, path.c_str(), tiles.size(), images.size());
  return tiles;
}

// --- BOP mode ---

// the colour image of image `im_id` in scene folder `folder`: rgb/ or gray/, PNG or JPEG (BOP's
// own sets also have .tif)
fs::path BopImagePath(const std::string& folder, int64_t im_id) {
  char name[32];
  std::snprintf(name, sizeof(name), "%06lld", static_cast<long long>(im_id));
  std::error_code error;
  for (const char* kind : {"rgb", "gray"}) {
    for (const char* extension : {".png", ".jpg", ".jpeg", ".tif"}) {
      const fs::path path = fs::path(folder) / kind / (std::string(name) + extension);
      if (fs::exists(path, error)) return path;
    }
  }
  throw std::runtime_error(folder + ": image " + std::to_string(im_id) + " has no rgb/" + name +
                           ".png, .jpg (nor gray/)");
}

std::vector<Tile> ReadBopTiles(const Flags& flags) {
  // the split
  std::error_code error;
  if (!fs::is_directory(flags.bop_dir, error)) {
    throw std::runtime_error("--bop " + flags.bop_dir + ": no such folder");
  }
  const std::string split = stackgen::FindBopSplit(flags.bop_dir, flags.split);
  if (split.empty()) {
    throw std::runtime_error("--bop " + flags.bop_dir +
                             ": no BOP split folder in it (SPLIT/SCENE_ID/scene_gt.json)");
  }

  // the first N images, scene by scene
  stackgen::BopSceneFiles files;
  files.info = true;
  std::vector<Tile> tiles;
  int64_t scene_folders = 0;
  for (const auto& [scene_id, folder] : stackgen::ListBopScenes(split)) {
    if (static_cast<int>(tiles.size()) >= flags.count) break;
    ++scene_folders;
    const stackgen::BopScene bop_scene = stackgen::ReadBopScene(scene_id, folder, files);
    for (const stackgen::BopImage& image : bop_scene.images) {
      if (static_cast<int>(tiles.size()) >= flags.count) break;
      const fs::path image_path = BopImagePath(folder, image.im_id);
      SceneView scene;
      scene.image = cv::imread(image_path.string(), cv::IMREAD_COLOR);
      if (scene.image.empty()) {
        throw std::runtime_error("cannot read " + image_path.string() +
                                 " (not an image OpenCV can decode, or damaged)");
      }
      // each ground truth's visible mask, its colour from visib_fract
      int hidden = 0;
      for (size_t gt_id = 0; gt_id < image.ground_truths.size(); ++gt_id) {
        const stackgen::BopGroundTruth& truth = image.ground_truths[gt_id];
        char name[32];
        std::snprintf(name, sizeof(name), "%06lld_%06zu.png", static_cast<long long>(image.im_id),
                      gt_id);
        const fs::path mask_path = fs::path(folder) / "mask_visib" / name;
        InstanceView instance;
        if (!fs::exists(mask_path, error)) {
          throw std::runtime_error(
              mask_path.string() + " is missing (" + (fs::path(folder) / "scene_gt.json").string() +
              " has image " + std::to_string(image.im_id) + ", gt " + std::to_string(gt_id) + ")");
        }
        instance.mask = cv::imread(mask_path.string(), cv::IMREAD_GRAYSCALE);
        if (instance.mask.empty()) {
          throw std::runtime_error("cannot read " + mask_path.string() +
                                   " (not an image OpenCV can decode, or damaged)");
        }
        if (instance.mask.size() != scene.image.size()) {
          throw std::runtime_error(
              mask_path.string() + " is " + std::to_string(instance.mask.cols) + " x " +
              std::to_string(instance.mask.rows) + ", its image " + image_path.string() + " " +
              std::to_string(scene.image.cols) + " x " + std::to_string(scene.image.rows));
        }
        if (cv::countNonZero(instance.mask) == 0) {
          ++hidden;
          continue;
        }
        instance.label =
            truth.visib_fract >= stackgen::kBopMinVisibFract ? Label::kAnnotated : Label::kIgnored;
        instance.instance_id = static_cast<int64_t>(gt_id);
        instance.visib_fract = truth.visib_fract;
        scene.instances.push_back(std::move(instance));
      }
      scene.caption = std::to_string(scene_id) + "/" + std::to_string(image.im_id) + ": " +
                      CountsText(scene.instances, false) + ", " + std::to_string(hidden) +
                      " hidden";
      tiles.push_back({RenderTile(scene, flags.tile_width), scene.caption});
    }
  }
  std::printf("%s: %s: %zu images of %lld scene folders\n", kProgram, split.c_str(), tiles.size(),
              static_cast<long long>(scene_folders));
  return tiles;
}

// --- bus mode ---

// What stackgen-view says when it stops waiting for scenes: what it skipped; an error when no
// valid scene came (naming a bus key mismatch first); a warning when fewer than asked came.
void ReportEnd(const stackgen::ConsumerSession& session, const Flags& flags, size_t tiles) {
  const stackgen::Bus& bus = session.bus();
  const int64_t undecodable = session.undecodable(), invalid = session.refused(),
                repeated = session.repeats();
  if (undecodable > 0 || invalid > 0 || repeated > 0) {
    std::fprintf(stderr,
                 "%s: skipped %lld undecodable messages, %lld invalid scenes, %lld repeated "
                 "scenes\n",
                 kProgram, static_cast<long long>(undecodable), static_cast<long long>(invalid),
                 static_cast<long long>(repeated));
  }
  if (tiles == 0) {
    const std::string mismatch = bus.state().KeyMismatch(GeneratorChannels(), 0);
    if (!mismatch.empty()) throw std::runtime_error(mismatch);
    throw std::runtime_error("--lcm-url " + bus.url() + ": no valid scene on " +
                             stackgen::kSceneChannel + " within " +
                             std::to_string(static_cast<int>(std::ceil(flags.timeout_s))) + " s");
  }
  if (static_cast<int>(tiles) < flags.count) {
    std::fprintf(stderr, "%s: only %zu of %d scenes arrived %s\n", kProgram, tiles, flags.count,
                 stop_requested ? "before the signal" : "before the timeout");
  }
}

std::vector<Tile> ReceiveBusTiles(const Flags& flags) {
  // stop waiting on SIGINT and SIGTERM: the handler only sets a flag
  stackgen::StopOnSignals(RequestStop);

  // a best-effort consumer: it sends no credits, and its counters go out on STACKGEN_STATUS
  stackgen::ConsumerSessionOptions options;
  options.process = kProgram;
  options.name = std::string(kProgram) + "/" + std::to_string(getpid());
  options.generator_channels = GeneratorChannels();
  options.key_mismatch_s = kKeyMismatchS;
  stackgen::ConsumerSession session(
      std::make_unique<stackgen::Bus>(
          stackgen::ResolveLcmUrl(flags.lcm_url),
          stackgen::ConsumerBusOptions(flags.fault_drop, flags.bus_key_file, flags.open_bus,
                                       flags.replay, 0x5EE)),
      options);
  const stackgen::Bus& bus = session.bus();
  std::vector<Tile> tiles;
  const auto warn = [](int64_t number, const std::string& text) {
    if (number <= kMaxReportedWarnings) {
      std::fprintf(stderr, "%s: warning: %s\n", kProgram, text.c_str());
    }
  };
  const stackgen::Subscription scenes = session.SubscribeScenes(
      stackgen::kSceneChannel,
      [&](const stackgen::scene& scene) {
        if (static_cast<int>(tiles.size()) >= flags.count) return;
        const int32_t generator_id = scene.header.generator_id;
        const int64_t seq = scene.header.seq;
        // a bad scene is skipped and counted, never drawn (a good copy may still come)
        try {
          const SceneView view = ViewOfMessage(scene);
          if (!session.Fresh(generator_id, seq)) return;
          tiles.push_back({RenderTile(view, flags.tile_width), view.caption});
        } catch (const std::exception& error) {
          session.Refuse(generator_id, seq);
          warn(session.refused(), "skipped scene " + std::to_string(generator_id) + "/" +
                                      std::to_string(seq) + ": " + error.what());
        }
      },
      kQueueCapacity,
      [&](const std::string& text) { warn(session.undecodable(), "skipped a message: " + text); });
  // the generators' configs too, for their key alone: each announces its config before its
  // first scene
  session.WatchGeneratorKeys();
  std::printf("%s: listening on %s channel %s for %d scenes\n", kProgram, bus.url().c_str(),
              stackgen::kSceneChannel, flags.count);
  std::fflush(stdout);

  // scenes until enough, the timeout or a signal; generators that use another key: a warning
  // now, and the reason at the timeout (an open viewer reads signed scenes all the same)
  // (the process's clock, through the seam: bus/clock.h)
  const stackgen::Clock& clock = stackgen::SteadyClock();
  const auto deadline =
      clock.Now() + std::chrono::duration_cast<stackgen::Clock::TimePoint::duration>(
                        std::chrono::duration<double>(flags.timeout_s));
  const auto held = [&] { return static_cast<int64_t>(tiles.size()); };
  while (!stop_requested && static_cast<int>(tiles.size()) < flags.count &&
         clock.Now() < deadline && !bus.state().log_ended()) {
    session.bus().HandleFor(100);
    session.Service(held(), held());
  }
  session.Leave(
      held(), held(),
      static_cast<int>(tiles.size()) >= flags.count ? stackgen::kRunEnded : stackgen::kRunStopped);
  ReportEnd(session, flags, tiles.size());
  return tiles;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  try {
    const bool bop = !flags.bop_dir.empty();
    const std::vector<Tile> tiles = flags.bus ? ReceiveBusTiles(flags)
                                    : bop     ? ReadBopTiles(flags)
                                              : ReadCocoTiles(flags);
    if (tiles.empty()) {
      throw std::runtime_error((bop ? "--bop " + flags.bop_dir : "--coco " + flags.coco_dir) +
                               ": no images");
    }
    const cv::Mat sheet = ComposeSheet(tiles, flags.columns, flags.tile_width, bop);
    WritePng(sheet, flags.out);
    const int columns = std::min<int>(flags.columns, static_cast<int>(tiles.size()));
    const int rows = (static_cast<int>(tiles.size()) + columns - 1) / columns;
    std::printf("%s: wrote %s: %zu scenes in %d columns x %d rows, %d x %d px\n", kProgram,
                flags.out.c_str(), tiles.size(), columns, rows, sheet.cols, sheet.rows);
    return 0;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
    return 1;
  }
}
