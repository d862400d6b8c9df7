#pragma once

// Reading a dataset in the BOP format as stackgen-bop writes it (consumers/bop/bop_writer.h):
// its split folder, the scene (chunk) folders in it and their JSON records. Shared by
// stackgen-stats and stackgen-view; the images and masks are left to them.

#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace stackgen {

/// The split read when none is named: BOP's synthetic training images.
constexpr const char* kDefaultBopSplit = "train_pbr";

/// BOP has no annotated flag: the tools count a ground truth at least this visible (visib_fract)
/// as annotated, the generator's default annotation.min_visib_fract.
constexpr double kBopMinVisibFract = 0.3;

/// One ground truth of an image: its record in scene_gt.json and, when read, in
/// scene_gt_info.json.
struct BopGroundTruth {
  /// obj_id: the class id (models/obj_OBJ_ID.ply).
  int64_t obj_id = 0;
  /// cam_R_m2c, row-major, as written (not checked to be a rotation).
  std::array<double, 9> camera_R_object{};
  /// cam_t_m2c, millimetres, camera frame.
  std::array<double, 3> camera_t_object_mm{};
  /// visib_fract of scene_gt_info.json, 0..1; NaN when that file was not read.
  double visib_fract = std::nan("");
  /// px_count_visib of scene_gt_info.json, pixels; -1 when that file was not read.
  int64_t px_count_visib = -1;
};

/// One image of a scene folder.
struct BopImage {
  int64_t im_id = 0;
  /// cam_R_w2c of scene_camera.json, row-major (not checked to be a rotation); zeros when that
  /// file was not read.
  std::array<double, 9> camera_R_world{};
  /// cam_t_w2c of scene_camera.json, millimetres; zeros when that file was not read.
  std::array<double, 3> camera_t_world_mm{};
  /// Its ground truths in gt id order (the GT_ID of the mask files).
  std::vector<BopGroundTruth> ground_truths;
};

/// One scene folder (BOP "scene"; a chunk of 1000 images in stackgen-bop's datasets).
struct BopScene {
  int64_t scene_id = 0;
  std::string folder;
  /// The images of scene_gt.json, by image id.
  std::vector<BopImage> images;
  /// Class names by obj_id, from the "categories" of scene_gt_coco.json; empty when that file
  /// was not read or is absent.
  std::map<int64_t, std::string> class_names;
};

/// Which files ReadBopScene reads besides scene_gt.json.
struct BopSceneFiles {
  /// scene_camera.json (then required): a record for every image of scene_gt.json.
  bool camera = false;
  /// scene_gt_info.json (then required): a record for every ground truth of scene_gt.json.
  bool info = false;
  /// scene_gt_coco.json, when present: the class names of its "categories".
  bool class_names = false;
};

/// The split folder of the BOP dataset in folder `dir`: DIR/`split` when `split` is not empty
/// (it must be a folder); else DIR/train_pbr when that is a folder, else the only subfolder of
/// DIR that holds a scene folder (named by a number) with a scene_gt.json. Returns "" when
/// `split` is empty and DIR holds no such folder (so is no BOP dataset). Throws
/// std::runtime_error naming DIR when `split` is not a folder of it, or when several subfolders
/// could be the split (it lists them).
std::string FindBopSplit(const std::string& dir, const std::string& split);

/// The scene folders of `split_folder` (its subfolders named by a number), by scene id. Throws
/// std::runtime_error naming the folder when it cannot be listed, holds no scene folder, or a
/// scene folder has no scene_gt.json (stackgen-bop writes a chunk's JSON files once it holds
/// 1000 images, the others when it ends).
std::vector<std::pair<int64_t, std::string>> ListBopScenes(const std::string& split_folder);

/// Reads the records of scene folder `folder`: scene_gt.json and the files `files` asks for.
/// Throws std::runtime_error with one line naming the file and, where there is one, the image,
/// ground truth and field at fault (see BopRecordName): a file that is missing or not valid JSON,
/// a key that is not an image id, a field missing or of the wrong type, an image of
/// scene_gt.json without its record in scene_camera.json or scene_gt_info.json, a different
/// number of ground truths there, a visib_fract outside 0..1.
BopScene ReadBopScene(int64_t scene_id, const std::string& folder, const BopSceneFiles& files);

/// How errors name a record: "FOLDER/FILE: image IM_ID" and ", gt GT_ID" when `gt_id` >= 0.
std::string BopRecordName(const std::string& folder, const std::string& file, int64_t im_id,
                          int64_t gt_id = -1);

}  // namespace stackgen
