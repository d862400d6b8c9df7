#include "consumers/bop/bop_dataset.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <system_error>

#include <nlohmann/json.hpp>

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// the longest number read as a scene or image id (fits int64_t)
constexpr size_t kMaxIdDigits = 18;

// `text` as a non-negative id, or -1 when it is not one (only digits, at most kMaxIdDigits)
int64_t IdOf(const std::string& text) {
  if (text.empty() || text.size() > kMaxIdDigits ||
      !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    return -1;
  }
  return std::stoll(text);
}

// the subfolders of `dir` named by a number, by that number; throws naming `dir` when it cannot
// be listed
std::map<int64_t, fs::path> NumberedFolders(const fs::path& dir) {
  std::map<int64_t, fs::path> folders;
  std::error_code error;
  fs::directory_iterator entries(dir, error);
  if (error) throw std::runtime_error(dir.string() + ": cannot list (" + error.message() + ")");
  for (const fs::directory_entry& entry : entries) {
    const int64_t id = IdOf(entry.path().filename().string());
    if (id >= 0 && entry.is_directory(error)) folders[id] = entry.path();
  }
  return folders;
}

// whether `dir` holds a scene folder with a scene_gt.json
bool HoldsBopScene(const fs::path& dir) {
  std::error_code error;
  fs::directory_iterator entries(dir, error);
  if (error) return false;
  for (const fs::directory_entry& entry : entries) {
    if (IdOf(entry.path().filename().string()) >= 0 &&
        fs::is_regular_file(entry.path() / "scene_gt.json", error)) {
      return true;
    }
  }
  return false;
}

// the JSON object in `path` (scene files: keyed by image id); throws naming the file
json ReadObjectFile(const fs::path& path) {
  std::ifstream file(path);
  if (!file) throw std::runtime_error(path.string() + ": cannot read");
  json root;
  try {
    root = json::parse(file);
  } catch (const json::exception& error) {
    throw std::runtime_error(path.string() + ": not valid JSON (" + error.what() + ")");
  }
  if (!root.is_object()) throw std::runtime_error(path.string() + ": not a JSON object");
  return root;
}

// the N numbers at `field` of `record` into `out`; throws `where` + the fault
template <size_t N>
void ReadNumbers(const json& record, const char* field, const std::string& where,
                 std::array<double, N>* out) {
  const auto found = record.find(field);
  if (found == record.end() || !found->is_array() || found->size() != N) {
    throw std::runtime_error(where + ": " + field + " is missing or not " + std::to_string(N) +
                             " numbers");
  }
  for (size_t k = 0; k < N; ++k) {
    if (!(*found)[k].is_number()) {
      throw std::runtime_error(where + ": " + field + "[" + std::to_string(k) +
                               "] is not a number");
    }
    (*out)[k] = (*found)[k].get<double>();
  }
}

// the integer at `field` of `record`; throws `where` + the fault
int64_t ReadInteger(const json& record, const char* field, const std::string& where) {
  const auto found = record.find(field);
  if (found == record.end() || !found->is_number_integer()) {
    throw std::runtime_error(where + ": " + field + " is missing or not an integer");
  }
  return found->get<int64_t>();
}

// the record list of image `im_id` in `records` (a scene_gt or scene_gt_info file) as an array
// of objects; throws naming the file and image
const json& ImageRecords(const json& records, const std::string& key, const std::string& folder,
                         const char* file, int64_t im_id) {
  const auto found = records.find(key);
  if (found == records.end()) {
    throw std::runtime_error(BopRecordName(folder, file, im_id) +
                             " is missing (scene_gt.json has it)");
  }
  if (!found->is_array()) {
    throw std::runtime_error(BopRecordName(folder, file, im_id) + " is not a list of records");
  }
  for (size_t k = 0; k < found->size(); ++k) {
    if (!(*found)[k].is_object()) {
      throw std::runtime_error(BopRecordName(folder, file, im_id, static_cast<int64_t>(k)) +
                               " is not a JSON object");
    }
  }
  return *found;
}

// Each ground truth's visib_fract and px_count_visib, from the scene's scene_gt_info.json
// (`keys`: each image id's key in the files).
void ReadVisibility(const std::string& folder, const std::map<int64_t, std::string>& keys,
                    BopScene* scene) {
  const fs::path dir(folder);
  const json info = ReadObjectFile(dir / "scene_gt_info.json");
  for (BopImage& image : scene->images) {
    const json& records =
        ImageRecords(info, keys.at(image.im_id), folder, "scene_gt_info.json", image.im_id);
    if (records.size() != image.ground_truths.size()) {
      throw std::runtime_error(BopRecordName(folder, "scene_gt_info.json", image.im_id) + " has " +
                               std::to_string(records.size()) + " ground truths, scene_gt.json " +
                               std::to_string(image.ground_truths.size()));
    }
    for (size_t k = 0; k < records.size(); ++k) {
      const std::string where =
          BopRecordName(folder, "scene_gt_info.json", image.im_id, static_cast<int64_t>(k));
      const auto found = records[k].find("visib_fract");
      if (found == records[k].end() || !found->is_number()) {
        throw std::runtime_error(where + ": visib_fract is missing or not a number");
      }
      const double visib_fract = found->get<double>();
      if (!(visib_fract >= 0.0 && visib_fract <= 1.0)) {
        throw std::runtime_error(where + ": visib_fract " + found->dump() + " is outside 0..1");
      }
      image.ground_truths[k].visib_fract = visib_fract;
      const int64_t px_count_visib = ReadInteger(records[k], "px_count_visib", where);
      if (px_count_visib < 0) {
        throw std::runtime_error(where + ": px_count_visib " + std::to_string(px_count_visib) +
                                 " is negative");
      }
      image.ground_truths[k].px_count_visib = px_count_visib;
    }
  }
}

// The class names of the scene's COCO file `coco_path` (scene_gt_coco.json), if it is there.
void ReadClassNames(const fs::path& coco_path, BopScene* scene) {
  std::error_code error;
  if (!fs::exists(coco_path, error)) return;
  const json coco = ReadObjectFile(coco_path);
  const auto categories = coco.find("categories");
  if (categories == coco.end() || !categories->is_array()) {
    throw std::runtime_error(coco_path.string() + ": categories is missing or not a list");
  }
  for (size_t k = 0; k < categories->size(); ++k) {
    const json& category = (*categories)[k];
    const std::string where = coco_path.string() + ": categories[" + std::to_string(k) + "]";
    if (!category.is_object()) throw std::runtime_error(where + " is not a JSON object");
    const int64_t id = ReadInteger(category, "id", where);
    const auto name = category.find("name");
    if (name == category.end() || !name->is_string()) {
      throw std::runtime_error(where + ": name is missing or not a string");
    }
    scene->class_names[id] = name->get<std::string>();
  }
}

}  // namespace

std::string BopRecordName(const std::string& folder, const std::string& file, int64_t im_id,
                          int64_t gt_id) {
  std::string name = (fs::path(folder) / file).string() + ": image " + std::to_string(im_id);
  if (gt_id >= 0) name += ", gt " + std::to_string(gt_id);
  return name;
}

std::string FindBopSplit(const std::string& dir, const std::string& split) {
  std::error_code error;
  // a split named: it must be there
  if (!split.empty()) {
    const fs::path named = fs::path(dir) / split;
    if (!fs::is_directory(named, error)) {
      throw std::runtime_error(dir + " has no split folder " + split);
    }
    return named.string();
  }
  // the default split, else the only folder holding scenes
  const fs::path preferred = fs::path(dir) / kDefaultBopSplit;
  if (fs::is_directory(preferred, error)) return preferred.string();
  std::vector<std::string> candidates;
  fs::directory_iterator entries(dir, error);
  if (error) throw std::runtime_error(dir + ": cannot list (" + error.message() + ")");
  for (const fs::directory_entry& entry : entries) {
    if (entry.is_directory(error) && HoldsBopScene(entry.path())) {
      candidates.push_back(entry.path().filename().string());
    }
  }
  std::sort(candidates.begin(), candidates.end());
  if (candidates.empty()) return "";
  if (candidates.size() > 1) {
    std::string names;
    for (const std::string& name : candidates) names += (names.empty() ? "" : ", ") + name;
    throw std::runtime_error(dir + " holds several BOP splits (" + names + ") and no " +
                             kDefaultBopSplit + ": name one with --split");
  }
  return (fs::path(dir) / candidates.front()).string();
}

std::vector<std::pair<int64_t, std::string>> ListBopScenes(const std::string& split_folder) {
  std::vector<std::pair<int64_t, std::string>> scenes;
  for (const auto& [scene_id, folder] : NumberedFolders(split_folder)) {
    std::error_code error;
    if (!fs::is_regular_file(folder / "scene_gt.json", error)) {
      throw std::runtime_error(folder.string() +
                               " has no scene_gt.json (stackgen-bop writes a chunk's JSON files "
                               "once it holds 1000 images, the others when it ends)");
    }
    scenes.emplace_back(scene_id, folder.string());
  }
  if (scenes.empty()) {
    throw std::runtime_error(split_folder + " holds no scene folder (SCENE_ID/scene_gt.json)");
  }
  return scenes;
}

BopScene ReadBopScene(int64_t scene_id, const std::string& folder, const BopSceneFiles& files) {
  BopScene scene;
  scene.scene_id = scene_id;
  scene.folder = folder;
  const fs::path dir(folder);

  // the images and their ground truths, by image id
  const json gt = ReadObjectFile(dir / "scene_gt.json");
  std::map<int64_t, std::string> keys;
  for (auto entry = gt.begin(); entry != gt.end(); ++entry) {
    const std::string& key = entry.key();
    const int64_t im_id = IdOf(key);
    if (im_id < 0) {
      throw std::runtime_error((dir / "scene_gt.json").string() + ": key \"" + key +
                               "\" is not an image id");
    }
    keys[im_id] = key;
  }
  for (const auto& [im_id, key] : keys) {
    BopImage image;
    image.im_id = im_id;
    const json& records = ImageRecords(gt, key, folder, "scene_gt.json", im_id);
    for (size_t k = 0; k < records.size(); ++k) {
      const std::string where =
          BopRecordName(folder, "scene_gt.json", im_id, static_cast<int64_t>(k));
      BopGroundTruth truth;
      truth.obj_id = ReadInteger(records[k], "obj_id", where);
      ReadNumbers(records[k], "cam_R_m2c", where, &truth.camera_R_object);
      ReadNumbers(records[k], "cam_t_m2c", where, &truth.camera_t_object_mm);
      image.ground_truths.push_back(truth);
    }
    scene.images.push_back(std::move(image));
  }

  // the camera of every image
  if (files.camera) {
    const json camera = ReadObjectFile(dir / "scene_camera.json");
    for (BopImage& image : scene.images) {
      const std::string where = BopRecordName(folder, "scene_camera.json", image.im_id);
      const auto record = camera.find(keys.at(image.im_id));
      if (record == camera.end()) {
        throw std::runtime_error(where + " is missing (scene_gt.json has it)");
      }
      if (!record->is_object()) throw std::runtime_error(where + " is not a JSON object");
      ReadNumbers(*record, "cam_R_w2c", where, &image.camera_R_world);
      ReadNumbers(*record, "cam_t_w2c", where, &image.camera_t_world_mm);
    }
  }

  // how much of every ground truth shows
  if (files.info) ReadVisibility(folder, keys, &scene);

  // the class names, when the COCO file is there
  if (files.class_names) ReadClassNames(dir / "scene_gt_coco.json", &scene);
  return scene;
}

}  // namespace stackgen
