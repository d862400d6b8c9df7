#include "consumers/bop/bop_writer.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "consumers/bop/model_files.h"
#include "consumers/bop/toolkit_json.h"
#include "consumers/dataset/files.h"
#include "consumers/dataset/grasp_records.h"
#include "consumers/dataset/images.h"
#include "consumers/dataset/shards.h"
#include "contract/rle.h"
#include "contract/scene_contract.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kJournalFile = "bop.journal";
constexpr const char* kCameraFile = "camera.json";
constexpr const char* kModelsFolder = "models";
constexpr const char* kModelsInfoFile = "models_info.json";
constexpr const char* kShardsFolder = "shards";
constexpr const char* kKeyToShardFile = "key_to_shard.json";
constexpr int kJournalVersion = 1;
// chunks (BOP scene folders) of kImagesPerChunk images (consumers/dataset/shards.h), and the
// ids that fit six digits
constexpr int64_t kChunksPerGenerator = 1000000;
constexpr int32_t kMaxObjId = 999999;
// scene_gt_coco "ignore": as the toolkit's scripts/calc_gt_coco.py, below 10 % visible
constexpr double kIgnoreBelowVisibFract = 0.1;
// masks are simple: the fastest zlib level makes them about as small as the default
constexpr int kMaskPngCompression = 1;

// the folders of a chunk's images
constexpr const char* kDepthFolder = "depth";
constexpr const char* kDepthIdealFolder = "depth_ideal";
constexpr const char* kPointsFolder = "points";
constexpr const char* kMaskFolder = "mask";
constexpr const char* kMaskVisibFolder = "mask_visib";
const char* const kImageFolders[] = {"rgb",       "gray", kDepthFolder, kDepthIdealFolder,
                                     kPointsFolder, kMaskFolder, kMaskVisibFolder};

// six digits, as BOP names its files and folders
std::string Six(int64_t value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%06lld", static_cast<long long>(value));
  return text;
}

// a mask in BOP-imagewise's mask.json form: uncompressed COCO RLE (pycoco_utils
// binary_mask_to_rle)
json UncompressedRle(const std::string& counts, int32_t height, int32_t width) {
  return {{"counts", StringToRuns(counts)}, {"size", {height, width}}};
}

bool AllFinite(const std::vector<std::vector<float>>& rows) {
  for (const auto& row : rows) {
    for (float value : row) {
      if (!std::isfinite(value)) return false;
    }
  }
  return true;
}

// the rotation (row-major) and translation of target_from_source's inverse
void Invert(const pose& target_from_source, std::vector<double>* rotation,
            std::vector<double>* translation) {
  const double* r = target_from_source.rotation;
  const double* t = target_from_source.translation_mm;
  rotation->assign(9, 0.0);
  translation->assign(3, 0.0);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*rotation)[i * 3 + j] = r[j * 3 + i];
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*translation)[i] -= r[j * 3 + i] * t[j];
  }
}

// a box (x, y, width, height in pixels, as the messages hold it) as the toolkit's
// misc.calc_2d_bbox gives it for the pixels of a mask: width and height one less (max - min),
// and [-1, -1, -1, -1] for a mask of no pixels (calc_gt_info.py gives that for bbox_obj too when
// nothing of the object is visible)
std::vector<int32_t> ToolkitBox(const int32_t box[4], int32_t pixels) {
  if (pixels <= 0) return {-1, -1, -1, -1};
  return {box[0], box[1], box[2] - 1, box[3] - 1};
}

// whether `name` is a file this writer gives an image: IM_ID.png|.jpg or IM_ID_GT_ID.png
bool IsImageFileName(const std::string& name) {
  const size_t dot = name.rfind('.');
  if (dot == std::string::npos) return false;
  const std::string stem = name.substr(0, dot), extension = name.substr(dot);
  if (extension != ".png" && extension != ".jpg") return false;
  const auto digits = [](const std::string& text) {
    return text.size() >= 6 &&
           std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
  };
  const size_t underscore = stem.find('_');
  if (underscore == std::string::npos) return digits(stem);
  return digits(stem.substr(0, underscore)) && digits(stem.substr(underscore + 1));
}

// the shards of the chunk in folder `chunk`, chunk `scene_id`, from its journal records (by image
// id), into `shards` with at most `shard_images` images each
void WriteShards(const fs::path& chunk, int64_t scene_id,
                 const std::vector<std::pair<int64_t, json>>& records, int shard_images,
                 const fs::path& shards_folder) {
  // the members of each shard, image by image in key order
  std::map<int64_t, std::vector<std::pair<std::string, std::string>>> shards;
  for (const auto& [im_id, record] : records) {
    const json& scene = record.at("scene");
    const std::string key = Six(scene_id) + "_" + Six(im_id);
    const std::string rgb = scene.at("rgb").get<std::string>();  // "rgb/000000.png"
    const size_t slash = rgb.find('/'), dot = rgb.rfind('.');
    const int32_t height = scene.at("height").get<int32_t>();
    const int32_t width = scene.at("width").get<int32_t>();
    json mask = json::object(), mask_visib = json::object();
    for (size_t g = 0; g < record.at("masks").size(); ++g) {
      mask[std::to_string(g)] = UncompressedRle(record["masks"][g][0], height, width);
      mask_visib[std::to_string(g)] = UncompressedRle(record["masks"][g][1], height, width);
    }
    const auto read = [&](const std::string& relative) {
      return ReadWholeFile((chunk / relative).string());
    };
    auto& members = shards[ShardOf(scene_id, im_id, shard_images)];
    members.emplace_back(key + "." + rgb.substr(0, slash) + rgb.substr(dot), read(rgb));
    members.emplace_back(key + ".depth.png",
                         read(std::string(kDepthFolder) + "/" + Six(im_id) + ".png"));
    const std::string ideal = std::string(kDepthIdealFolder) + "/" + Six(im_id) + ".png";
    if (fs::exists(chunk / ideal)) members.emplace_back(key + ".depth_ideal.png", read(ideal));
    members.emplace_back(key + ".camera.json", ToolkitText(record.at("camera")));
    members.emplace_back(key + ".gt.json", ToolkitText(record.at("gt")));
    members.emplace_back(key + ".gt_info.json", ToolkitText(record.at("gt_info")));
    members.emplace_back(key + ".mask.json", ToolkitText(mask, true));
    members.emplace_back(key + ".mask_visib.json", ToolkitText(mask_visib, true));
  }
  for (const auto& [shard_id, members] : shards) {
    WriteTar(shards_folder / ShardFileName(shard_id), members);
  }
}

// writes a file of a scene (a path relative to its chunk folder) and remembers it
using FileWriter = std::function<void(const std::string& relative, const std::vector<uint8_t>&)>;

// a scene's ground truths in BOP's records, by instance id
struct GroundTruths {
  json gt = json::array();       // scene_gt: pose and class
  json gt_info = json::array();  // scene_gt_info: boxes and pixel counts
  json coco = json::array();     // scene_gt_coco: the visible ones
  json masks = json::array();    // the full and visible masks' RLEs, for the journal
  json grasps = json::array();   // scene_grasp: each ground truth's grasps (if any)
  int64_t count = 0;
};

// the ground truths of `scene` (image `im_id`), ordered by instance id; writes each one's full
// and visible mask images through `write` and notes its class in `classes`
GroundTruths MakeGroundTruths(const scene& scene, int64_t im_id, const cv::Mat& depth,
                              const FileWriter& write, std::map<int32_t, std::string>* classes) {
  const camera_info& camera = scene.camera;
  GroundTruths out;
  std::vector<const instance*> objects;
  for (const instance& object : scene.instances) objects.push_back(&object);
  std::sort(objects.begin(), objects.end(),
            [](const instance* a, const instance* b) { return a->instance_id < b->instance_id; });
  cv::Mat mask(camera.height, camera.width, CV_8UC1);
  for (size_t gt_id = 0; gt_id < objects.size(); ++gt_id) {
    const instance& object = *objects[gt_id];
    const std::string mask_name = Six(im_id) + "_" + Six(static_cast<int64_t>(gt_id)) + ".png";
    // the full mask: its pixels with a depth are BOP's px_count_valid
    mask.setTo(0);
    DecodeRleInto(object.mask_obj_rle, camera.height, camera.width, mask.data);
    const int64_t valid = cv::countNonZero(mask & (depth > 0));
    write(std::string(kMaskFolder) + "/" + mask_name, EncodeImage(mask * 255, kMaskPngCompression));
    mask.setTo(0);
    DecodeRleInto(object.mask_visib_rle, camera.height, camera.width, mask.data);
    write(std::string(kMaskVisibFolder) + "/" + mask_name,
          EncodeImage(mask * 255, kMaskPngCompression));

    const pose& camera_from_object = object.camera_from_object;
    out.gt.push_back({{"cam_R_m2c", std::vector<double>(camera_from_object.rotation,
                                                        camera_from_object.rotation + 9)},
                      {"cam_t_m2c", std::vector<double>(camera_from_object.translation_mm,
                                                        camera_from_object.translation_mm + 3)},
                      {"obj_id", object.class_id}});
    out.gt_info.push_back(
        {{"bbox_obj",
          ToolkitBox(object.bbox_obj, object.px_count_visib > 0 ? object.px_count_all : 0)},
         {"bbox_visib", ToolkitBox(object.bbox_visib, object.px_count_visib)},
         {"px_count_all", object.px_count_all},
         {"px_count_valid", valid},
         {"px_count_visib", object.px_count_visib},
         {"visib_fract", object.visib_fract}});
    if (object.px_count_visib > 0) {
      out.coco.push_back(
          {{"area", object.px_count_visib},
           {"bbox", std::vector<int32_t>(object.bbox_obj, object.bbox_obj + 4)},
           {"category_id", object.class_id},
           {"height", camera.height},
           {"ignore", object.visib_fract < kIgnoreBelowVisibFract},
           {"image_id", im_id},
           {"iscrowd", 0},
           {"segmentation",
            {{"counts", object.mask_visib_rle}, {"size", {camera.height, camera.width}}}},
           {"width", camera.width}});
    }
    out.masks.push_back({object.mask_obj_rle, object.mask_visib_rle});
    if (scene.num_suction_grasps > 0 || scene.num_jaw_grasps > 0) {
      out.grasps.push_back(GraspsJson(scene, object.instance_id));
    }
    classes->emplace(object.class_id, object.class_name);
  }
  out.count = static_cast<int64_t>(objects.size());
  return out;
}

// a scene's camera record: K, world to camera, depth scale
json SceneCamera(const camera_info& camera) {
  std::vector<double> rotation, translation;
  Invert(camera.world_from_camera, &rotation, &translation);
  return {{"cam_K", {camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0}},
          {"cam_R_w2c", rotation},
          {"cam_t_w2c", translation},
          {"depth_scale", camera.depth_scale_mm}};
}

// camera.json: the first scene's camera, which describes the dataset's sensor.
void WriteCameraFile(const fs::path& path, const camera_info& camera) {
  WriteToolkitObject(path, {{"cx", camera.cx},
                            {"cy", camera.cy},
                            {"depth_scale", camera.depth_scale_mm},
                            {"fx", camera.fx},
                            {"fy", camera.fy},
                            {"height", camera.height},
                            {"width", camera.width}});
}

// The "scene" part of a scene's journal line: its ids, size, seed, colour file, classes and
// files (relative to `dir`).
json JournalScene(const scene& scene, int64_t scene_id, int64_t im_id, const std::string& rgb_name,
                  const std::map<int32_t, std::string>& class_names,
                  const std::vector<std::string>& paths, const std::string& dir) {
  json classes = json::array();
  for (const auto& [class_id, class_name] : class_names) classes.push_back({class_id, class_name});
  json files = json::array();
  for (const std::string& path : paths) {
    files.push_back(fs::path(path).lexically_relative(dir).string());
  }
  return {{"classes", std::move(classes)},
          {"files", std::move(files)},
          {"generator_id", scene.header.generator_id},
          {"height", scene.camera.height},
          {"im_id", im_id},
          {"journal_version", kJournalVersion},
          {"rgb", rgb_name},
          {"scene_id", scene_id},
          {"seed", scene.header.seed},
          {"seq", scene.header.seq},
          {"width", scene.camera.width}};
}

}  // namespace

int64_t BopWriter::SceneId(int32_t generator_id, int64_t seq) {
  return int64_t{generator_id} * kChunksPerGenerator + seq / kImagesPerChunk;
}

int64_t BopWriter::ImageId(int64_t seq) { return seq % kImagesPerChunk; }

std::string BopWriter::ChunkFolder(int64_t scene_id) const {
  return options_.split + "/" + Six(scene_id);
}

BopWriter::BopWriter(const std::string& dir, const BopWriterOptions& options)
    : dir_(dir), options_(options) {
  static_assert(kMaxSeq / kImagesPerChunk < kChunksPerGenerator, "chunks of two generators meet");
  if (options_.jpeg_quality < 0 || options_.jpeg_quality > 100) {
    throw std::runtime_error("jpeg_quality " + std::to_string(options_.jpeg_quality) +
                             " outside 0..100");
  }
  if (options_.shard_images < 0 || options_.shard_images > kImagesPerChunk) {
    throw std::runtime_error("shard_images " + std::to_string(options_.shard_images) +
                             " outside 0..1000");
  }
  if (options_.split.empty() || options_.split.find('/') != std::string::npos ||
      options_.split == "." || options_.split == ".." || options_.split == kModelsFolder) {
    throw std::runtime_error("split \"" + options_.split +
                             "\" is not a folder name (BOP: train_pbr, train, val, test)");
  }
  const fs::path folder(dir_);
  const std::string journal_path = (folder / kJournalFile).string();
  if (!options_.resume && FileSize(journal_path) > 0) {
    throw DatasetStartedError(journal_path);
  }

  // the folders, and the journal, locked; a writer that cannot open leaves nothing it made
  std::vector<fs::path> created = CreateFolders(folder / kModelsFolder);
  if (options_.shard_images > 0) {
    for (const fs::path& path : CreateFolders(folder / kShardsFolder)) created.push_back(path);
  }
  const bool journal_existed = FileSize(journal_path) >= 0;
  try {
    journal_ = std::make_unique<Journal>(journal_path);
    std::set<std::string> journaled_files;
    if (options_.resume) {
      truncated_journal_bytes_ =
          journal_->Load([&](const std::string& line, uint64_t offset, int64_t line_number) {
            LoadJournalLine(line, offset, line_number, &journaled_files);
          });
      // every chunk's JSON files are made again by Finish: a crash may have come between a
      // commit and the files
      for (const auto& [key, entry] : index_) dirty_chunks_.insert(key.first);
    } else if (journal_->size() > 0) {
      throw DatasetStartedError(journal_path);
    }
    CleanFolders(journaled_files);

    // what an earlier run stored of the models and the camera
    const fs::path models_info = folder / kModelsFolder / kModelsInfoFile;
    if (FileSize(models_info.string()) > 0) {
      const json info = json::parse(ReadWholeFile(models_info.string()), nullptr, false);
      if (!info.is_object()) {
        throw std::runtime_error(models_info.string() + " is not a JSON object (damaged?)");
      }
      for (const auto& [key, entry] : info.items()) {
        models_info_[std::stoi(key)] = entry.dump();
      }
    }
    camera_written_ = FileSize((folder / kCameraFile).string()) > 0;
    SyncFolder(folder);
  } catch (...) {
    journal_.reset();
    if (!journal_existed && FileSize(journal_path) == 0) unlink(journal_path.c_str());
    std::error_code ignored;
    for (const fs::path& path : created) fs::remove(path, ignored);  // only if empty
    throw;
  }
}

BopWriter::~BopWriter() = default;

void BopWriter::LoadJournalLine(const std::string& line, uint64_t offset, int64_t line_number,
                                std::set<std::string>* files) {
  const std::string where = journal_->path() + " line " + std::to_string(line_number) + " (byte " +
                            std::to_string(offset) + ")";
  try {
    const json record = json::parse(line);
    const json& scene = record.at("scene");
    if (scene.at("journal_version") != kJournalVersion) {
      throw std::runtime_error("journal_version " + scene["journal_version"].dump() + " is not " +
                               std::to_string(kJournalVersion));
    }
    Entry entry;
    const int64_t generator_id = scene.at("generator_id").get<int64_t>();
    entry.seq = scene.at("seq").get<int64_t>();
    entry.seed = scene.at("seed").get<int64_t>();
    if (generator_id < 0 || generator_id > kMaxGeneratorId ||
        !SceneIdsInRange(static_cast<int32_t>(generator_id), entry.seq)) {
      throw std::runtime_error("scene " + std::to_string(generator_id) + "/" +
                               std::to_string(entry.seq) + " is outside the id layout");
    }
    entry.generator_id = static_cast<int32_t>(generator_id);
    if (scene.at("scene_id") != SceneId(entry.generator_id, entry.seq) ||
        scene.at("im_id") != ImageId(entry.seq)) {
      throw std::runtime_error("scene_id or im_id does not match generator_id and seq");
    }
    if (index_.count({SceneId(entry.generator_id, entry.seq), ImageId(entry.seq)}) != 0) {
      throw std::runtime_error("scene " + std::to_string(generator_id) + "/" +
                               std::to_string(entry.seq) + " is recorded twice");
    }
    if (scene.contains("run")) runs_[entry.generator_id] = scene["run"].get<std::string>();
    for (const json& file : scene.at("files")) files->insert(file.get<std::string>());
    for (const json& category : scene.at("classes")) {
      const int32_t class_id = category.at(0).get<int32_t>();
      const std::string name = category.at(1).get<std::string>();
      const auto known = classes_.find(class_id);
      if (known != classes_.end() && known->second != name) {
        throw std::runtime_error("class " + std::to_string(class_id) + " \"" + name +
                                 "\" differs from an earlier line's \"" + known->second + "\"");
      }
      classes_.emplace(class_id, name);
    }
    num_ground_truths_ += static_cast<int64_t>(record.at("gt").size());
    entry.offset = offset;
    entry.length = line.size();
    Index(entry);
  } catch (const json::exception& error) {
    throw std::runtime_error(where + ": not a stackgen-bop journal record (" + error.what() + ")");
  } catch (const std::runtime_error& error) {
    throw std::runtime_error(where + ": " + error.what());
  }
}

void BopWriter::CleanFolders(const std::set<std::string>& journaled_files) const {
  const fs::path root(dir_);
  size_t present = 0;
  const auto clean = [&](const fs::path& folder, bool images) {
    present += CleanUnrecorded(root, folder, journaled_files, images, IsImageFileName);
  };
  clean(root, false);
  clean(root / kModelsFolder, false);
  clean(root / kShardsFolder, false);
  const fs::path split = root / options_.split;
  std::error_code error;
  for (fs::directory_iterator chunk(split, error), end; !error && chunk != end;
       chunk.increment(error)) {
    std::error_code type_error;
    if (!chunk->is_directory(type_error)) continue;
    clean(chunk->path(), false);
    for (const char* images : kImageFolders) clean(chunk->path() / images, options_.resume);
  }
  CheckRecordedFiles(root, journaled_files, present, journal_->path());
}

void BopWriter::Index(const Entry& entry) {
  index_.emplace(std::make_pair(SceneId(entry.generator_id, entry.seq), ImageId(entry.seq)), entry);
}

void BopWriter::Validate(const scene& scene) const {
  std::string why;
  if (!CheckScene(scene, &why)) FailScene(scene, why);
  if (scene.depth.size == 0)
    FailScene(scene, "depth is empty: a BOP dataset needs the depth image");
  // what BOP needs beyond the contract: obj ids of six digits, JSON text, one name per class
  std::map<int32_t, std::string> scene_classes;
  for (size_t i = 0; i < scene.instances.size(); ++i) {
    const instance& object = scene.instances[i];
    const std::string field = "instances[" + std::to_string(i) + "]";
    if (object.class_id > kMaxObjId) {
      FailScene(scene, field + ".class_id " + std::to_string(object.class_id) + " outside 1.." +
                           std::to_string(kMaxObjId) + " (BOP obj ids have six digits)");
    }
    if (!IsUtf8(object.class_name)) FailScene(scene, field + ".class_name is not valid UTF-8");
    std::string known = scene_classes.emplace(object.class_id, object.class_name).first->second;
    const auto stored = classes_.find(object.class_id);
    if (stored != classes_.end()) known = stored->second;
    for (const Staged& staged : staged_) {
      const auto in_staged = staged.classes.find(object.class_id);
      if (in_staged != staged.classes.end()) known = in_staged->second;
    }
    if (known != object.class_name) {
      FailScene(scene, field + ".class_name \"" + object.class_name + "\" differs from \"" + known +
                           "\" seen before for class_id " + std::to_string(object.class_id));
    }
  }
}

bool BopWriter::Add(const scene& scene) {
  // store each (generator_id, seq) once; the same ids with another seed come from another run
  const int32_t generator_id = scene.header.generator_id;
  const int64_t seq = scene.header.seq;
  CheckSceneIds(scene);
  const int64_t scene_id = SceneId(generator_id, seq);
  const int64_t im_id = ImageId(seq);
  const auto key = std::make_pair(scene_id, im_id);
  if (IsRepeat(scene, SeenSeed(index_, staged_seeds_, key))) return false;
  Validate(scene);

  // the images, decoded whole: a PNG or JPEG is checked before it is stored
  std::string why;
  const cv::Mat color = DecodeImage(scene.color, &why);
  if (color.empty()) FailScene(scene, "color." + why);
  const cv::Mat depth = DecodeImage(scene.depth, &why);
  if (depth.empty()) FailScene(scene, "depth." + why);
  // a 3D camera's depth goes to depth/, the exact one beside it
  const bool sensor = scene.depth_sensor.size > 0;
  cv::Mat sensor_depth;
  if (sensor) {
    sensor_depth = DecodeImage(scene.depth_sensor, &why);
    if (sensor_depth.empty()) FailScene(scene, "depth_sensor." + why);
  }

  // where its files go
  const camera_info& camera = scene.camera;
  const std::string chunk = ChunkFolder(scene_id);
  const fs::path chunk_path = fs::path(dir_) / chunk;
  const bool gray = scene.color.pixel_format == image::PIXEL_GRAY8;
  const bool jpeg = options_.jpeg_quality > 0 || scene.color.encoding == image::ENCODING_JPEG;
  const std::string rgb_name =
      std::string(gray ? "gray/" : "rgb/") + Six(im_id) + (jpeg ? ".jpg" : ".png");
  Staged staged;
  try {
    for (const char* folder :
         {gray ? "gray" : "rgb", kDepthFolder, kMaskFolder, kMaskVisibFolder}) {
      CreateFolders(chunk_path / folder);
    }
    if (sensor) CreateFolders(chunk_path / kDepthIdealFolder);
    if (options_.point_clouds) CreateFolders(chunk_path / kPointsFolder);
    const FileWriter write = [&](const std::string& relative, const std::vector<uint8_t>& bytes) {
      const fs::path path = chunk_path / relative;
      staged.files.push_back(path.string());
      WriteFileAtomically(path, reinterpret_cast<const char*>(bytes.data()), bytes.size(), false);
    };

    // colour and depth: the bytes as they came where they are the file BOP wants
    const bool keep_color = scene.color.encoding == image::ENCODING_JPEG ||
                            (scene.color.encoding == image::ENCODING_PNG && !jpeg);
    write(rgb_name, keep_color ? scene.color.data : EncodeImage(color, -1, options_.jpeg_quality));
    const auto depth_file = [](const image& message, const cv::Mat& pixels) {
      return message.encoding == image::ENCODING_PNG ? message.data : EncodeImage(pixels, -1);
    };
    write(std::string(kDepthFolder) + "/" + Six(im_id) + ".png",
          sensor ? depth_file(scene.depth_sensor, sensor_depth) : depth_file(scene.depth, depth));
    if (sensor) {
      write(std::string(kDepthIdealFolder) + "/" + Six(im_id) + ".png",
            depth_file(scene.depth, depth));
    }
    if (options_.point_clouds) {
      write(std::string(kPointsFolder) + "/" + Six(im_id) + ".ply",
            PointCloudPly(sensor ? sensor_depth : depth, camera));
    }

    // the ground truths, by instance id, and their mask images
    GroundTruths truths = MakeGroundTruths(scene, im_id, depth, write, &staged.classes);
    staged.ground_truths = truths.count;

    if (!camera_written_) {
      // the first scene's camera describes the dataset's sensor
      WriteCameraFile(fs::path(dir_) / kCameraFile, camera);
      camera_written_ = true;
    }

    // its journal line
    json record_scene =
        JournalScene(scene, scene_id, im_id, rgb_name, staged.classes, staged.files, dir_);
    const auto run = runs_.find(generator_id);
    if (run != runs_.end()) record_scene["run"] = run->second;
    json record = {{"camera", SceneCamera(camera)},    {"coco", std::move(truths.coco)},
                   {"gt", std::move(truths.gt)},       {"gt_info", std::move(truths.gt_info)},
                   {"masks", std::move(truths.masks)}, {"scene", std::move(record_scene)}};
    if (scene.num_suction_grasps > 0 || scene.num_jaw_grasps > 0) {
      record["grasps"] = std::move(truths.grasps);
    }
    staged.line = record.dump() + "\n";
  } catch (...) {
    for (const std::string& path : staged.files) unlink(path.c_str());
    throw;
  }
  // where it lies in the line: from its start, without the '\n'
  staged.entry = Entry{generator_id, seq, scene.header.seed, 0, staged.line.size() - 1};
  staged_seeds_.emplace(key, scene.header.seed);
  staged_.push_back(std::move(staged));
  if (!options_.group_commit) Commit();
  return true;
}

std::vector<std::pair<int32_t, int64_t>> BopWriter::Commit() {
  std::vector<std::pair<int32_t, int64_t>> committed;
  if (staged_.empty()) return committed;
  // on failure nothing staged stays: its files go
  std::vector<std::string> lines, files;
  for (const Staged& staged : staged_) {
    lines.push_back(staged.line);
    files.insert(files.end(), staged.files.begin(), staged.files.end());
  }
  uint64_t offset = 0;
  try {
    offset = CommitGroup(journal_.get(), lines, files, true, dir_);
  } catch (...) {
    staged_.clear();
    staged_seeds_.clear();
    throw;
  }
  // index them where their lines now lie
  std::set<int64_t> chunks;
  for (const Staged& staged : staged_) {
    Entry entry = staged.entry;
    entry.offset = offset;
    Index(entry);
    classes_.insert(staged.classes.begin(), staged.classes.end());
    num_ground_truths_ += staged.ground_truths;
    committed.emplace_back(entry.generator_id, entry.seq);
    chunks.insert(SceneId(entry.generator_id, entry.seq));
    offset += staged.line.size();
  }
  staged_.clear();
  staged_seeds_.clear();
  // a chunk with all its images gets its JSON files now, the others at Finish
  for (const int64_t scene_id : chunks) {
    const auto first = index_.lower_bound({scene_id, 0});
    const auto last = index_.lower_bound({scene_id + 1, 0});
    if (std::distance(first, last) == kImagesPerChunk) {
      WriteChunk(scene_id);
      dirty_chunks_.erase(scene_id);
    } else {
      dirty_chunks_.insert(scene_id);
    }
  }
  return committed;
}

void BopWriter::WriteChunk(int64_t scene_id) {
  json scene_camera = json::object(), scene_gt = json::object(), scene_gt_info = json::object();
  std::vector<std::pair<int64_t, json>> cameras, gts, infos, grasps;
  json images = json::array(), annotations = json::array();
  std::map<int32_t, std::string> chunk_classes;
  // each image's journal record, read and parsed once for the files and the shards
  std::vector<std::pair<int64_t, json>> records;
  for (auto it = index_.lower_bound({scene_id, 0});
       it != index_.end() && it->first.first == scene_id; ++it) {
    records.emplace_back(it->first.second,
                         json::parse(journal_->Read(it->second.offset, it->second.length)));
  }
  int64_t annotation_id = 1;
  for (const auto& [im_id, record] : records) {
    cameras.emplace_back(im_id, record["camera"]);
    gts.emplace_back(im_id, record["gt"]);
    infos.emplace_back(im_id, record["gt_info"]);
    if (record.contains("grasps")) grasps.emplace_back(im_id, record["grasps"]);
    for (json annotation : record["coco"]) {
      annotation["id"] = annotation_id++;
      annotations.push_back(std::move(annotation));
    }
    for (const json& category : record["scene"]["classes"]) {
      chunk_classes.emplace(category[0].get<int32_t>(), category[1].get<std::string>());
    }
    const json& scene = record["scene"];
    images.push_back({{"file_name", scene["rgb"]},
                      {"height", scene["height"]},
                      {"id", im_id},
                      {"width", scene["width"]}});
  }

  // the per-image files, keyed by image id in numeric order, as save_json sorts int keys
  const fs::path folder = fs::path(dir_) / ChunkFolder(scene_id);
  const auto write = [&](const char* name, const std::vector<std::pair<int64_t, json>>& items) {
    std::vector<std::pair<std::string, const json*>> entries;
    for (const auto& [im_id, value] : items) entries.emplace_back(std::to_string(im_id), &value);
    WriteToolkitFile(folder / name, entries);
  };
  write("scene_camera.json", cameras);
  write("scene_gt.json", gts);
  write("scene_gt_info.json", infos);
  if (!grasps.empty()) write("scene_grasp.json", grasps);

  // scene_gt_coco.json: annotations numbered in image order; categories of this chunk
  json categories = json::array();
  for (const auto& [class_id, class_name] : chunk_classes) {
    categories.push_back({{"id", class_id}, {"name", class_name}, {"supercategory", "stackgen"}});
  }
  const json coco = {{"annotations", std::move(annotations)},
                     {"categories", std::move(categories)},
                     {"images", std::move(images)},
                     {"info",
                      {{"contributor", "stackgen-bop"},
                       {"description", "stackgen " + options_.split + " " + Six(scene_id)},
                       {"url", ""},
                       {"version", "1.0"}}},
                     {"licenses", json::array()}};
  WriteToolkitObject(folder / "scene_gt_coco.json", coco);
  if (options_.shard_images > 0) {
    WriteShards(folder, scene_id, records, options_.shard_images, fs::path(dir_) / kShardsFolder);
  }
}

int64_t BopWriter::ShardId(int64_t scene_id, int64_t im_id) const {
  return ShardOf(scene_id, im_id, options_.shard_images);
}

void BopWriter::WriteKeyToShard() const {
  std::map<std::string, int64_t> keys;
  for (const auto& [key, entry] : index_) {
    keys.emplace(Six(key.first) + "_" + Six(key.second), ShardId(key.first, key.second));
  }
  stackgen::WriteKeyToShard(fs::path(dir_) / kShardsFolder / kKeyToShardFile, keys);
}

void BopWriter::Finish() {
  Commit();
  for (const int64_t scene_id : dirty_chunks_) WriteChunk(scene_id);
  dirty_chunks_.clear();
  if (options_.shard_images > 0) WriteKeyToShard();
}

bool BopWriter::AddModel(const model& m) {
  // a model that agrees with itself
  const std::string name = "model of class " + std::to_string(m.class_id);
  const auto fail = [&](const std::string& text) { throw InvalidSceneError(name + ": " + text); };
  if (m.class_id < 1 || m.class_id > kMaxObjId) {
    fail("class_id outside 1.." + std::to_string(kMaxObjId));
  }
  if (m.class_name.empty() || !IsUtf8(m.class_name)) fail("class_name is empty or not UTF-8");
  if (m.num_vertices < 3 || m.num_vertices != static_cast<int32_t>(m.vertices_mm.size()) ||
      m.num_vertices != static_cast<int32_t>(m.normals.size()) || m.num_triangles < 1 ||
      m.num_triangles != static_cast<int32_t>(m.triangles.size())) {
    fail("num_vertices " + std::to_string(m.num_vertices) + " or num_triangles " +
         std::to_string(m.num_triangles) + " does not match the arrays or is too small");
  }
  if (!AllFinite(m.vertices_mm) || !AllFinite(m.normals)) fail("a vertex or normal is not finite");
  for (const std::vector<int32_t>& t : m.triangles) {
    for (int32_t index : t) {
      if (index < 0 || index >= m.num_vertices) fail("a triangle index is outside the vertices");
    }
  }
  if (!std::isfinite(m.diameter_mm) || m.diameter_mm <= 0) fail("diameter_mm is not positive");
  if (m.num_discrete_symmetries != static_cast<int32_t>(m.discrete_symmetries.size()) ||
      m.num_continuous_symmetries != static_cast<int32_t>(m.continuous_axes.size()) ||
      m.num_continuous_symmetries != static_cast<int32_t>(m.continuous_offsets_mm.size())) {
    fail("a symmetry count does not match its array");
  }
  for (const auto* rows : {&m.discrete_symmetries, &m.continuous_axes, &m.continuous_offsets_mm}) {
    for (const std::vector<double>& row : *rows) {
      for (double value : row) {
        if (!std::isfinite(value)) fail("a symmetry is not finite");
      }
    }
  }
  // the class in the data must be the model's
  const auto known = classes_.find(m.class_id);
  if (known != classes_.end() && known->second != m.class_name) {
    fail("class_name \"" + m.class_name + "\" differs from the scenes' \"" + known->second + "\"");
  }

  // the first model heard of a class is kept; another mesh for it is reported, not stored
  const std::string ply = PlyText(m);
  const fs::path ply_path = fs::path(dir_) / kModelsFolder / ("obj_" + Six(m.class_id) + ".ply");
  if (models_info_.count(m.class_id) != 0) {
    auto heard = model_files_.find(m.class_id);
    if (heard == model_files_.end()) {
      // stored by an earlier run: compare with its file once
      const bool present = FileSize(ply_path.string()) >= 0;
      heard =
          model_files_.emplace(m.class_id, present ? ReadWholeFile(ply_path.string()) : "").first;
    }
    if (heard->second != ply) conflicting_models_.insert(m.class_id);
    return false;
  }
  WriteFileAtomically(ply_path, ply.data(), ply.size(), true);
  models_info_[m.class_id] = ModelInfo(m).dump();
  model_files_[m.class_id] = ply;
  WriteModelsInfo();
  return true;
}

void BopWriter::WriteModelsInfo() const {
  // keyed by obj id in numeric order, as save_json sorts int keys
  std::vector<json> values;
  values.reserve(models_info_.size());
  for (const auto& [obj_id, text] : models_info_) values.push_back(json::parse(text));
  std::vector<std::pair<std::string, const json*>> entries;
  size_t i = 0;
  for (const auto& [obj_id, text] : models_info_) {
    entries.emplace_back(std::to_string(obj_id), &values[i++]);
  }
  WriteToolkitFile(fs::path(dir_) / kModelsFolder / kModelsInfoFile, entries);
}

std::set<int32_t> BopWriter::ModelClasses() const {
  std::set<int32_t> classes;
  for (const auto& [obj_id, text] : models_info_) classes.insert(obj_id);
  return classes;
}

int64_t BopWriter::num_chunks() const {
  std::set<int64_t> chunks;
  for (const auto& [key, entry] : index_) chunks.insert(key.first);
  return static_cast<int64_t>(chunks.size());
}

std::map<int32_t, std::vector<int64_t>> BopWriter::StoredSeqs() const {
  // the index is sorted by scene id (generator, then seq / 1000), then image id (seq % 1000)
  std::map<int32_t, std::vector<int64_t>> seqs;
  for (const auto& [key, entry] : index_) seqs[entry.generator_id].push_back(entry.seq);
  return seqs;
}

std::map<int32_t, int64_t> BopWriter::LostPerGenerator() const { return LostBetween(StoredSeqs()); }

void BopWriter::SetRun(int32_t generator_id, const std::string& run) { runs_[generator_id] = run; }

}  // namespace stackgen
