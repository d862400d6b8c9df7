#include "research/stats/dataset.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stackgen/labels.hpp>
#include <stackgen/scene.hpp>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "bus/auth.h"
#include "bus/channels.h"
#include "bus/log.h"
#include "gen/annotate/pose.h"
#include "consumers/bop/bop_dataset.h"

namespace stackgen::stats {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// tolerance on R^T R = I and det R = 1 for rotations read from a file
constexpr double kRotationTolerance = 1e-6;
// below this |(w, z)| of the unit quaternion the heading is undefined
constexpr double kHeadingUndefined = 1e-9;
// parts of two scenes closer than this in every coordinate, mm, lie in one place: one pile. Logs
// and COCO files repeat a pile's poses exactly; a BOP dataset gives each view's through its own
// camera, and the positions computed back from them differ by about 1e-12 mm
constexpr double kSamePositionMm = 1e-6;

// the reference frame of `class_name`, identity when none is set
Eigen::Matrix3d ReferenceOf(const ReadOptions& options, const std::string& class_name) {
  const auto found = options.object_R_reference.find(class_name);
  return found == options.object_R_reference.end() ? Eigen::Matrix3d::Identity() : found->second;
}

// a rotation from 9 row-major values; throws `where` + the fault if it is not one
Eigen::Matrix3d RotationFromRowMajor(const double* values, const std::string& where) {
  Eigen::Matrix3d rotation;
  for (int k = 0; k < 9; ++k) {
    if (!std::isfinite(values[k])) {
      throw std::runtime_error(where + "[" + std::to_string(k) + "] is not finite");
    }
    rotation(k / 3, k % 3) = values[k];
  }
  const double orthonormal_error =
      (rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double determinant = rotation.determinant();
  if (orthonormal_error > kRotationTolerance || std::fabs(determinant - 1.0) > kRotationTolerance) {
    std::ostringstream text;
    text << where << " is not a rotation (|R^T R - I| = " << orthonormal_error
         << ", det = " << determinant << ")";
    throw std::runtime_error(text.str());
  }
  return rotation;
}

// adds one instance to `dataset`, or counts why it is left out
void AddInstance(const std::string& class_name, const Eigen::Matrix3d& world_R_object,
                 const Eigen::Vector3d& world_position_mm, int resting_face, int64_t scene,
                 const ReadOptions& options, Dataset* dataset) {
  if (!options.class_name.empty() && class_name != options.class_name) {
    ++dataset->other_class;
    return;
  }
  PostureSample sample = PostureOf(world_R_object, ReferenceOf(options, class_name));
  sample.class_name = class_name;
  sample.resting_face = resting_face;
  sample.scene = scene;
  sample.world_position_mm = world_position_mm;
  dataset->samples.push_back(std::move(sample));
  ++dataset->class_counts[class_name];
}

// the first character of the file that is not white space, or 0
char FirstNonSpace(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  char c = 0;
  while (file.get(c)) {
    if (c != ' ' && c != '\t' && c != '\n' && c != '\r') return c;
  }
  return 0;
}

// the number at `field` of `record`, or throws naming the file, the record and the field
double NumberAt(const json& record, const char* field, const std::string& where) {
  const auto found = record.find(field);
  if (found == record.end() || !found->is_number()) {
    throw std::runtime_error(where + "." + field + " is missing or not a number");
  }
  return found->get<double>();
}

// `count` numbers at `field` of `record`
std::vector<double> NumbersAt(const json& record, const char* field, size_t count,
                              const std::string& where) {
  const auto found = record.find(field);
  if (found == record.end() || !found->is_array() || found->size() != count) {
    throw std::runtime_error(where + "." + field + " is missing or not " + std::to_string(count) +
                             " numbers");
  }
  std::vector<double> values;
  for (const json& value : *found) {
    if (!value.is_number()) {
      throw std::runtime_error(where + "." + field + " holds something that is not a number");
    }
    values.push_back(value.get<double>());
  }
  return values;
}

// An annotation's rotation in the bin frame (world_R_m2w, else posture_deg), its position
// (world_t_m2w, else NaN) and its resting face (-1 when it has none); errors name `where`.
void ReadPose(const json& annotation, const std::string& where, Eigen::Matrix3d* world_R_object,
              Eigen::Vector3d* position, int* resting_face) {
  if (annotation.contains("world_R_m2w")) {
    const std::vector<double> values = NumbersAt(annotation, "world_R_m2w", 9, where);
    *world_R_object = RotationFromRowMajor(values.data(), where + ".world_R_m2w");
  } else if (annotation.contains("posture_deg")) {
    const std::vector<double> angles = NumbersAt(annotation, "posture_deg", 3, where);
    *world_R_object = RotationFromPostureDeg(Eigen::Vector3d(angles[0], angles[1], angles[2]));
  } else {
    throw std::runtime_error(where + " has neither world_R_m2w nor posture_deg");
  }
  if (annotation.contains("resting_face")) {
    *resting_face = static_cast<int>(NumberAt(annotation, "resting_face", where));
  }
  *position = Eigen::Vector3d::Constant(std::nan(""));
  if (annotation.contains("world_t_m2w")) {
    const std::vector<double> values = NumbersAt(annotation, "world_t_m2w", 3, where);
    *position = Eigen::Vector3d(values[0], values[1], values[2]);
    if (!position->allFinite()) throw std::runtime_error(where + ".world_t_m2w is not finite");
  }
}

void ReadCoco(const std::string& path, const ReadOptions& options, Dataset* dataset) {
  dataset->kind = "COCO";
  json root;
  {
    std::ifstream file(path);
    try {
      root = json::parse(file);
    } catch (const json::exception& error) {
      throw std::runtime_error(path + ": not valid JSON (" + std::string(error.what()) + ")");
    }
  }
  for (const char* field : {"images", "categories", "annotations"}) {
    if (!root.is_object() || !root.contains(field) || !root[field].is_array()) {
      throw std::runtime_error(path + ": not a COCO file (no \"" + field + "\" array)");
    }
  }
  dataset->scenes = static_cast<int64_t>(root["images"].size());
  // scenes by image id, in file order
  std::map<int64_t, int64_t> scene_of_image;
  for (size_t k = 0; k < root["images"].size(); ++k) {
    const std::string where = path + ": images[" + std::to_string(k) + "]";
    const json& image = root["images"][k];
    if (!image.is_object()) throw std::runtime_error(where + " is not an object");
    const auto id = static_cast<int64_t>(NumberAt(image, "id", where));
    if (!scene_of_image.emplace(id, static_cast<int64_t>(k)).second) {
      throw std::runtime_error(where + ".id " + std::to_string(id) + " is repeated");
    }
  }

  // class names by category id
  std::map<int64_t, std::string> names;
  for (size_t k = 0; k < root["categories"].size(); ++k) {
    const json& category = root["categories"][k];
    const std::string where = path + ": categories[" + std::to_string(k) + "]";
    if (!category.is_object() || !category.contains("name") || !category["name"].is_string()) {
      throw std::runtime_error(where + ".name is missing or not a string");
    }
    names[static_cast<int64_t>(NumberAt(category, "id", where))] = category["name"];
  }

  // every annotation: its class, rotation and resting face; ignore regions (iscrowd 1, instances
  // the generator did not annotate) only with all_instances
  const json& annotations = root["annotations"];
  for (size_t k = 0; k < annotations.size(); ++k) {
    const json& annotation = annotations[k];
    const std::string where = path + ": annotations[" + std::to_string(k) + "]";
    if (!annotation.is_object()) throw std::runtime_error(where + " is not an object");
    if (annotation.contains("iscrowd") && NumberAt(annotation, "iscrowd", where) != 0 &&
        !options.all_instances) {
      ++dataset->not_annotated;
      continue;
    }
    const int64_t category_id = static_cast<int64_t>(NumberAt(annotation, "category_id", where));
    const auto name = names.find(category_id);
    if (name == names.end()) {
      throw std::runtime_error(where + ".category_id " + std::to_string(category_id) +
                               " is not in categories");
    }
    Eigen::Matrix3d world_R_object;
    Eigen::Vector3d position;
    int resting_face = -1;
    ReadPose(annotation, where, &world_R_object, &position, &resting_face);
    const auto image_id = static_cast<int64_t>(NumberAt(annotation, "image_id", where));
    const auto scene = scene_of_image.find(image_id);
    if (scene == scene_of_image.end()) {
      throw std::runtime_error(where + ".image_id " + std::to_string(image_id) +
                               " is not in images");
    }
    AddInstance(name->second, world_R_object, position, resting_face, scene->second, options,
                dataset);
  }
}

// the ground truths of a BOP split folder, image by image in scene id, image id order; without
// all_instances only those at least kBopMinVisibFract visible (BOP has no annotated flag)
void ReadBop(const std::string& split_folder, const ReadOptions& options, Dataset* dataset) {
  dataset->kind = "BOP";
  dataset->split = fs::path(split_folder).filename().string();
  // the ground truths used, named once every scene's class names are known
  struct Truth {
    int64_t obj_id;
    Eigen::Matrix3d world_R_object;
    Eigen::Vector3d world_position_mm;
    int64_t scene;
  };
  std::vector<Truth> truths;
  std::map<int64_t, std::pair<std::string, std::string>> names;  // obj_id -> name, its file
  BopSceneFiles files;
  files.camera = true;
  files.info = !options.all_instances;
  files.class_names = true;
  for (const auto& [scene_id, folder] : ListBopScenes(split_folder)) {
    const BopScene scene = ReadBopScene(scene_id, folder, files);
    const std::string coco_path = (fs::path(folder) / "scene_gt_coco.json").string();
    for (const auto& [obj_id, name] : scene.class_names) {
      const auto [known, fresh] = names.try_emplace(obj_id, name, coco_path);
      if (!fresh && known->second.first != name) {
        throw std::runtime_error(coco_path + ": category " + std::to_string(obj_id) + " is \"" +
                                 name + "\", in " + known->second.second + " \"" +
                                 known->second.first + "\"");
      }
    }
    // each image is a scene; world_from_object = inverse(camera_from_world) camera_from_object
    for (const BopImage& image : scene.images) {
      const int64_t scene_number = dataset->scenes++;
      const std::string camera_where = BopRecordName(folder, "scene_camera.json", image.im_id);
      const Eigen::Matrix3d camera_R_world =
          RotationFromRowMajor(image.camera_R_world.data(), camera_where + ": cam_R_w2c");
      const Eigen::Vector3d camera_t_world(image.camera_t_world_mm.data());
      if (!camera_t_world.allFinite()) {
        throw std::runtime_error(camera_where + ": cam_t_w2c is not finite");
      }
      for (size_t k = 0; k < image.ground_truths.size(); ++k) {
        const BopGroundTruth& truth = image.ground_truths[k];
        if (!options.all_instances && !(truth.visib_fract >= kBopMinVisibFract)) {
          ++dataset->not_annotated;
          continue;
        }
        const std::string where =
            BopRecordName(folder, "scene_gt.json", image.im_id, static_cast<int64_t>(k));
        const Eigen::Matrix3d camera_R_object =
            RotationFromRowMajor(truth.camera_R_object.data(), where + ": cam_R_m2c");
        const Eigen::Vector3d camera_t_object(truth.camera_t_object_mm.data());
        if (!camera_t_object.allFinite()) {
          throw std::runtime_error(where + ": cam_t_m2c is not finite");
        }
        truths.push_back({truth.obj_id, camera_R_world.transpose() * camera_R_object,
                          camera_R_world.transpose() * (camera_t_object - camera_t_world),
                          scene_number});
      }
    }
  }
  for (const Truth& truth : truths) {
    const auto name = names.find(truth.obj_id);
    char fallback[32];
    std::snprintf(fallback, sizeof(fallback), "obj_%06lld", static_cast<long long>(truth.obj_id));
    AddInstance(name != names.end() ? name->second.first : std::string(fallback),
                truth.world_R_object, truth.world_position_mm, -1, truth.scene, options, dataset);
  }
}

// the instances of one labels or scene message
void AddMessageInstances(const std::vector<stackgen::instance>& instances, int64_t scene,
                         const std::string& where, const ReadOptions& options, Dataset* dataset) {
  for (size_t k = 0; k < instances.size(); ++k) {
    const stackgen::instance& instance = instances[k];
    if (!instance.annotated && !options.all_instances) {
      ++dataset->not_annotated;
      continue;
    }
    const Eigen::Matrix3d world_R_object = RotationFromRowMajor(
        instance.world_from_object.rotation,
        where + ".instances[" + std::to_string(k) + "].world_from_object.rotation");
    const double* t = instance.world_from_object.translation_mm;
    const Eigen::Vector3d position(t[0], t[1], t[2]);
    if (!position.allFinite()) {
      throw std::runtime_error(where + ".instances[" + std::to_string(k) +
                               "].world_from_object.translation_mm is not finite");
    }
    AddInstance(instance.class_name, world_R_object, position, instance.resting_face, scene,
                options, dataset);
  }
}

void ReadLcmLog(const std::string& path, const ReadOptions& options, Dataset* dataset) {
  dataset->kind = "LCM log";
  // scenes by (generator_id, seq): the labels and the scene of one render count once
  std::set<std::pair<int32_t, int64_t>> seen;
  int64_t messages = 0;
  // a log recorded with a bus key is read with it: what a stranger sent on the bus while it was
  // recorded is left out; with an open bus nothing is checked
  MessageAuth auth(options.open_bus ? "" : ResolveBusKeyFile(options.bus_key_file), false);
  KeyEvidence key_evidence;
  std::string first_refusal;
  try {
    const LogSummary summary = ReadLog(path, [&](const LogEvent& logged) {
      const bool is_labels = logged.channel == kLabelsChannel;
      const bool is_scene = logged.channel == kSceneChannel;
      if (!is_labels && !is_scene) return;
      std::string why;
      const int64_t body = auth.Open(logged.channel, logged.data, logged.size, &why);
      key_evidence.Note(auth, logged.data, logged.size, body >= 0);
      if (body < 0) {
        if (first_refusal.empty()) first_refusal = why;
        return;
      }
      LogEvent event = logged;
      event.size = static_cast<size_t>(body);
      ++messages;
      const std::string where =
          path + ": event " + std::to_string(event.number) + " on " + event.channel;
      if (is_labels) {
        const stackgen::labels labels = DecodeLogEvent<stackgen::labels>(event);
        if (!seen.emplace(labels.header.generator_id, labels.header.seq).second) {
          ++dataset->repeated_scenes;
          return;
        }
        AddMessageInstances(labels.instances, static_cast<int64_t>(seen.size()) - 1, where, options,
                            dataset);
      } else {
        const stackgen::scene scene = DecodeLogEvent<stackgen::scene>(event);
        if (!seen.emplace(scene.header.generator_id, scene.header.seq).second) {
          ++dataset->repeated_scenes;
          return;
        }
        AddMessageInstances(scene.instances, static_cast<int64_t>(seen.size()) - 1, where, options,
                            dataset);
      }
    });
    dataset->truncated_bytes = summary.truncated_bytes;
  } catch (const DecodeError& error) {
    throw std::runtime_error(path + ": " + error.what());
  }
  // every message refused for its key: one line saying so (not a warning and an error)
  const std::string mismatch = key_evidence.Mismatch(auth, "the messages of " + path);
  if (!mismatch.empty()) throw std::runtime_error(mismatch);
  if (auth.counters().total() > 0) {
    std::fprintf(stderr, "stackgen-stats: warning: %s: left out %lld messages (%s)\n", path.c_str(),
                 static_cast<long long>(auth.counters().total()), first_refusal.c_str());
  }
  if (messages == 0) {
    throw std::runtime_error(path + ": the log holds no " + std::string(kLabelsChannel) + " or " +
                             kSceneChannel + " messages" +
                             (first_refusal.empty() ? "" : " that pass the bus key check"));
  }
  dataset->scenes = static_cast<int64_t>(seen.size());
}

// scenes that share a part's position (within kSamePositionMm) show one pile
// (physics.views_per_pile: the same settled poses under other cameras; two piles of their own
// never share a position to a nanometre)
void AssignPiles(Dataset* dataset) {
  std::map<int64_t, int64_t> parent;  // union-find over scenes
  const std::function<int64_t(int64_t)> root = [&](int64_t scene) {
    int64_t& up = parent.try_emplace(scene, scene).first->second;
    if (up != scene) up = root(up);
    return up;
  };
  // positions in cells of kSamePositionMm: a match lies in the cell or a neighbour
  using Cell = std::tuple<int64_t, int64_t, int64_t>;
  std::map<Cell, std::vector<std::pair<Eigen::Vector3d, int64_t>>> scenes_at;
  for (const PostureSample& sample : dataset->samples) {
    root(sample.scene);
    const Eigen::Vector3d& p = sample.world_position_mm;
    if (!p.allFinite()) continue;
    const Eigen::Vector3d index = (p / kSamePositionMm).array().floor();
    const Cell cell(static_cast<int64_t>(index.x()), static_cast<int64_t>(index.y()),
                    static_cast<int64_t>(index.z()));
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        for (int64_t dz = -1; dz <= 1; ++dz) {
          const auto near = scenes_at.find(
              Cell(std::get<0>(cell) + dx, std::get<1>(cell) + dy, std::get<2>(cell) + dz));
          if (near == scenes_at.end()) continue;
          for (const auto& [position, scene] : near->second) {
            if ((position - p).cwiseAbs().maxCoeff() > kSamePositionMm) continue;
            const int64_t a = root(scene), b = root(sample.scene);
            if (a != b) parent[std::max(a, b)] = std::min(a, b);
          }
        }
      }
    }
    scenes_at[cell].emplace_back(p, sample.scene);
  }
  // piles numbered in the order of their first scene
  std::map<int64_t, int64_t> number;
  for (auto& [scene, unused] : parent)
    number.emplace(root(scene), static_cast<int64_t>(number.size()));
  for (PostureSample& sample : dataset->samples) sample.pile = number.at(root(sample.scene));
  dataset->piles = static_cast<int64_t>(number.size());
}

}  // namespace

double HeadingDeg(const Eigen::Matrix3d& world_R_reference) {
  // with q = q_z(heading) * q_swing and q_swing = (p, x, y, 0): q.w = cos(h/2) p, q.z = sin(h/2) p
  const Eigen::Quaterniond q(world_R_reference);
  if (std::hypot(q.w(), q.z()) < kHeadingUndefined) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  double heading = 2.0 * std::atan2(q.z(), q.w()) * 180.0 / M_PI;
  // q and -q give headings 360 degrees apart
  while (heading > 180.0) heading -= 360.0;
  while (heading <= -180.0) heading += 360.0;
  return heading;
}

PostureSample PostureOf(const Eigen::Matrix3d& world_R_object,
                        const Eigen::Matrix3d& object_R_reference) {
  const Eigen::Matrix3d world_R_reference = world_R_object * object_R_reference;
  const Eigen::Vector3d angles = PostureAnglesDeg(world_R_reference);
  PostureSample sample;
  sample.alpha_deg = angles[0];
  sample.beta_deg = angles[1];
  sample.gamma_deg = angles[2];
  sample.heading_deg = HeadingDeg(world_R_reference);
  return sample;
}

Dataset ReadDataset(const std::string& path, const ReadOptions& options) {
  Dataset dataset;
  dataset.path = path;
  // a COCO dataset folder stands for its annotations.json; a folder without is a BOP dataset
  std::error_code error;
  std::string file = path;
  if (fs::is_directory(path, error)) {
    file = (fs::path(path) / "annotations.json").string();
    if (!fs::exists(file, error)) {
      const std::string split = FindBopSplit(path, options.bop_split);
      if (split.empty()) {
        throw std::runtime_error(path +
                                 " is a folder without annotations.json (COCO) or a BOP split "
                                 "folder (SPLIT/SCENE_ID/scene_gt.json)");
      }
      ReadBop(split, options, &dataset);
      AssignPiles(&dataset);
      return dataset;
    }
  }
  if (!fs::exists(file, error)) throw std::runtime_error(file + " does not exist");
  {
    std::ifstream probe(file, std::ios::binary);
    if (!probe) throw std::runtime_error("cannot read " + file);
  }

  // the kind by content
  if (IsLcmLog(file)) {
    ReadLcmLog(file, options, &dataset);
  } else if (FirstNonSpace(file) == '{') {
    ReadCoco(file, options, &dataset);
  } else {
    throw std::runtime_error(file + " is neither a COCO file (JSON object) nor an LCM log");
  }
  AssignPiles(&dataset);
  return dataset;
}

}  // namespace stackgen::stats
