// Reading BOP datasets for the tools (consumers/bop/bop_dataset.h): which split folder is read, the scene
// folders and their records, and one-line errors naming the file and field for bad records.

#include "consumers/bop/bop_dataset.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using testing::ScratchDir;

// a scene folder of two images (ids 7 and 10, written out of order) as stackgen-bop writes them
constexpr const char* kSceneGt = R"({
  "10": [{"cam_R_m2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "cam_t_m2c": [1.0, 2.0, 400.0], "obj_id": 2}],
  "7": [{"cam_R_m2c": [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0], "cam_t_m2c": [-5.5, 0.0, 450.0], "obj_id": 1}, {"cam_R_m2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "cam_t_m2c": [0.0, 0.0, 460.0], "obj_id": 1}]
})";
constexpr const char* kSceneCamera = R"({
  "10": {"cam_K": [200.0, 0.0, 79.5, 0.0, 200.0, 59.5, 0.0, 0.0, 1.0], "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0], "cam_t_w2c": [0.0, 0.0, 450.0], "depth_scale": 0.1},
  "7": {"cam_K": [200.0, 0.0, 79.5, 0.0, 200.0, 59.5, 0.0, 0.0, 1.0], "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0], "cam_t_w2c": [3.0, 0.0, 455.0], "depth_scale": 0.1}
})";
constexpr const char* kSceneGtInfo = R"({
  "10": [{"bbox_obj": [1, 2, 3, 4], "bbox_visib": [1, 2, 3, 4], "px_count_all": 100, "px_count_valid": 100, "px_count_visib": 100, "visib_fract": 1.0}],
  "7": [{"bbox_obj": [1, 2, 3, 4], "bbox_visib": [-1, -1, -1, -1], "px_count_all": 80, "px_count_valid": 80, "px_count_visib": 0, "visib_fract": 0.0}, {"bbox_obj": [1, 2, 3, 4], "bbox_visib": [1, 2, 3, 4], "px_count_all": 90, "px_count_valid": 90, "px_count_visib": 18, "visib_fract": 0.2}]
})";
constexpr const char* kSceneGtCoco =
    R"({"annotations": [], "categories": [{"id": 1, "name": "corner_connector", "supercategory": "stackgen"}, {"id": 2, "name": "dowel_pin", "supercategory": "stackgen"}], "images": [], "info": {}, "licenses": []})";

// writes `text` to `path`, creating its folder
void Write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path) << text;
}

// a scene folder with the four JSON files above, some replaced by `overrides` (file -> text)
void WriteScene(const fs::path& folder, const std::map<std::string, std::string>& overrides = {}) {
  std::map<std::string, std::string> files = {{"scene_gt.json", kSceneGt},
                                              {"scene_camera.json", kSceneCamera},
                                              {"scene_gt_info.json", kSceneGtInfo},
                                              {"scene_gt_coco.json", kSceneGtCoco}};
  for (const auto& [name, text] : overrides) files[name] = text;
  for (const auto& [name, text] : files) Write(folder / name, text);
}

// the message of the std::runtime_error `read` throws, or "" when it throws none
template <typename Read>
std::string ErrorOf(Read read) {
  try {
    read();
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "";
}

BopSceneFiles AllFiles() {
  BopSceneFiles files;
  files.camera = true;
  files.info = true;
  files.class_names = true;
  return files;
}

// The split is the one named, else train_pbr, else the only folder holding scene folders with a
// scene_gt.json (models/ and shards/ are not splits); several such folders are an error naming
// them, and a folder without any gives "".
TEST(BopDatasetTest, FindsTheSplit) {
  const ScratchDir scratch;
  const fs::path dir = scratch.path();
  EXPECT_EQ(FindBopSplit(dir.string(), ""), "");
  fs::create_directories(dir / "models");
  Write(dir / "models" / "models_info.json", "{}");
  fs::create_directories(dir / "shards");
  WriteScene(dir / "test" / "000001");
  EXPECT_EQ(FindBopSplit(dir.string(), ""), (dir / "test").string());
  WriteScene(dir / "val" / "000000");
  EXPECT_EQ(ErrorOf([&] { FindBopSplit(dir.string(), ""); }),
            dir.string() + " holds several BOP splits (test, val) and no train_pbr: name one " +
                "with --split");
  EXPECT_EQ(FindBopSplit(dir.string(), "val"), (dir / "val").string());
  EXPECT_EQ(ErrorOf([&] { FindBopSplit(dir.string(), "train"); }),
            dir.string() + " has no split folder train");
  fs::create_directories(dir / "train_pbr");
  EXPECT_EQ(FindBopSplit(dir.string(), ""), (dir / "train_pbr").string());
}

// Scene folders are listed by their number; one without scene_gt.json (a chunk stackgen-bop has
// not finished) and a split without scene folders are errors naming the folder.
TEST(BopDatasetTest, ListsSceneFolders) {
  const ScratchDir scratch;
  const fs::path split = fs::path(scratch.path()) / "train_pbr";
  fs::create_directories(split / "notes");
  EXPECT_EQ(ErrorOf([&] { ListBopScenes(split.string()); }),
            split.string() + " holds no scene folder (SCENE_ID/scene_gt.json)");
  WriteScene(split / "2000000");
  WriteScene(split / "000010");
  const auto scenes = ListBopScenes(split.string());
  ASSERT_EQ(scenes.size(), 2u);
  EXPECT_EQ(scenes[0].first, 10);
  EXPECT_EQ(scenes[1].first, 2000000);
  EXPECT_EQ(scenes[1].second, (split / "2000000").string());
  fs::create_directories(split / "000011");
  EXPECT_EQ(ErrorOf([&] { ListBopScenes(split.string()); }),
            (split / "000011").string() +
                " has no scene_gt.json (stackgen-bop writes a chunk's JSON files once it holds "
                "1000 images, the others when it ends)");
}

// A scene folder's records: images by image id (7 before 10), ground truths in gt id order with
// their pose, class, camera, visibility, and the class names of scene_gt_coco.json.
TEST(BopDatasetTest, ReadsSceneRecords) {
  const ScratchDir scratch;
  const fs::path folder = fs::path(scratch.path()) / "000003";
  WriteScene(folder);
  const BopScene scene = ReadBopScene(3, folder.string(), AllFiles());
  EXPECT_EQ(scene.scene_id, 3);
  ASSERT_EQ(scene.images.size(), 2u);
  const BopImage& first = scene.images[0];
  EXPECT_EQ(first.im_id, 7);
  ASSERT_EQ(first.ground_truths.size(), 2u);
  EXPECT_EQ(first.ground_truths[0].obj_id, 1);
  EXPECT_EQ(first.ground_truths[0].camera_R_object[1], -1.0);
  EXPECT_EQ(first.ground_truths[0].camera_t_object_mm[0], -5.5);
  EXPECT_EQ(first.ground_truths[1].visib_fract, 0.2);
  EXPECT_EQ(first.ground_truths[1].px_count_visib, 18);
  EXPECT_EQ(first.camera_R_world[4], -1.0);
  EXPECT_EQ(first.camera_t_world_mm[0], 3.0);
  EXPECT_EQ(scene.images[1].im_id, 10);
  EXPECT_EQ(scene.images[1].ground_truths[0].obj_id, 2);
  EXPECT_EQ(scene.class_names.at(1), "corner_connector");
  EXPECT_EQ(scene.class_names.at(2), "dowel_pin");

  // only scene_gt.json unless asked: the other files may be missing
  for (const char* name : {"scene_camera.json", "scene_gt_info.json", "scene_gt_coco.json"}) {
    fs::remove(folder / name);
  }
  const BopScene bare = ReadBopScene(3, folder.string(), {});
  EXPECT_TRUE(std::isnan(bare.images[0].ground_truths[0].visib_fract));
  EXPECT_TRUE(bare.class_names.empty());
  BopSceneFiles names_only;
  names_only.class_names = true;
  EXPECT_TRUE(ReadBopScene(3, folder.string(), names_only).class_names.empty());
}

// A bad record is one line naming the file, the image, the ground truth and the field.
TEST(BopDatasetTest, BadRecordsNameFileAndField) {
  const ScratchDir scratch;
  const fs::path folder = fs::path(scratch.path()) / "000000";
  const std::string gt = (folder / "scene_gt.json").string();
  const std::string camera = (folder / "scene_camera.json").string();
  const std::string info = (folder / "scene_gt_info.json").string();
  const std::string coco = (folder / "scene_gt_coco.json").string();
  const std::string one_gt =
      R"([{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 400], "obj_id": 1}])";
  const std::string camera_record =
      R"({"cam_R_w2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_w2c": [0, 0, 0]})";
  const std::string info_record = R"([{"px_count_visib": 5, "visib_fract": 0.5}])";
  struct Case {
    std::map<std::string, std::string> files;
    std::string error;
  };
  const std::vector<Case> cases = {
      {{{"scene_gt.json", "{\"0\": " + one_gt + ", \"1\": " + one_gt + "}"},
        {"scene_camera.json", "{\"0\": " + camera_record + "}"}},
       camera + ": image 1 is missing (scene_gt.json has it)"},
      {{{"scene_gt.json",
         R"({"0": [{"cam_R_m2c": [1, 0, 0], "cam_t_m2c": [0, 0, 1], "obj_id": 1}]})"}},
       gt + ": image 0, gt 0: cam_R_m2c is missing or not 9 numbers"},
      {{{"scene_gt.json",
         R"({"0": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, "x", 1], "obj_id": 1}]})"}},
       gt + ": image 0, gt 0: cam_t_m2c[1] is not a number"},
      {{{"scene_gt.json",
         R"({"0": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1], "obj_id": 1.5}]})"}},
       gt + ": image 0, gt 0: obj_id is missing or not an integer"},
      {{{"scene_gt.json", "{\"first\": " + one_gt + "}"}},
       gt + ": key \"first\" is not an image id"},
      {{{"scene_gt.json", "{\"0\": " + one_gt}}, ""},  // not valid JSON: checked by prefix below
      {{{"scene_gt.json", "{\"0\": " + one_gt + "}"},
        {"scene_camera.json", "{\"0\": " + camera_record + "}"},
        {"scene_gt_info.json", R"({"0": []})"}},
       info + ": image 0 has 0 ground truths, scene_gt.json 1"},
      {{{"scene_gt.json", "{\"0\": " + one_gt + "}"},
        {"scene_camera.json", "{\"0\": " + camera_record + "}"},
        {"scene_gt_info.json", R"({"0": [{"px_count_visib": 5, "visib_fract": 1.5}]})"}},
       info + ": image 0, gt 0: visib_fract 1.5 is outside 0..1"},
      {{{"scene_gt.json", "{\"0\": " + one_gt + "}"},
        {"scene_camera.json", "{\"0\": " + camera_record + "}"},
        {"scene_gt_info.json", "{\"0\": " + info_record + "}"},
        {"scene_gt_coco.json", R"({"categories": [{"id": 1}]})"}},
       coco + ": categories[0]: name is missing or not a string"},
  };
  for (const Case& bad : cases) {
    fs::remove_all(folder);
    WriteScene(folder, bad.files);
    const std::string error = ErrorOf([&] { ReadBopScene(0, folder.string(), AllFiles()); });
    if (bad.error.empty()) {
      EXPECT_EQ(error.rfind(gt + ": not valid JSON (", 0), 0u) << error;
    } else {
      EXPECT_EQ(error, bad.error);
    }
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
}

}  // namespace
}  // namespace stackgen
