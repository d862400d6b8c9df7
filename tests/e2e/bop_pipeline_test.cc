// Starts stackgen-bop and stackgen as separate processes on a free multicast port and reads the
// BOP dataset back, field by field, against the same scenes and models made again in this process
// (scene k is a pure function of config, seed, generator id and k); then kills the writer mid-run
// and resumes it.

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "contract/rle.h"
#include "gen/config/config.h"
#include "gen/mesh/mesh.h"
#include "gen/scene/scene_generator.h"
#include "tests/support/datasets.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::Process;
using testing::ReadFile;

// mixed.pbtxt: corner connectors and dowel pins (two classes) and foam-block distractors
constexpr int kScenes = 6;
constexpr int kSeed = 7;
const std::string kBin = STACKGEN_BIN_DIR;
const std::string kConfig = std::string(STACKGEN_SOURCE_DIR) + "/config/mixed.pbtxt";

std::vector<std::string> Bop(const std::string& out, const std::string& url,
                             std::vector<std::string> extra = {}) {
  // shards of 4 images: two shards, one of them part full
  std::vector<std::string> argv = {kBin + "/stackgen-bop",
                                   "--out",
                                   out,
                                   "--count",
                                   std::to_string(kScenes),
                                   "--lcm-url",
                                   url,
                                   "--shards",
                                   "4"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

std::vector<std::string> Generator(const std::string& url, const std::string& cache) {
  return {kBin + "/stackgen",
          "--count",
          std::to_string(kScenes),
          "--seed",
          std::to_string(kSeed),
          "--config",
          kConfig,
          "--lcm-url",
          url,
          "--cache-dir",
          cache,
          "--consumer-timeout",
          "5"};
}

// colour images stored in chunk 0
int ImagesStored(const std::string& dataset) {
  std::error_code error;
  int count = 0;
  for (const auto& entry : fs::directory_iterator(dataset + "/train_pbr/000000/rgb", error)) {
    if (entry.path().extension() != ".tmp") ++count;
  }
  return count;
}

std::string Six(int value) {
  char text[16];
  std::snprintf(text, sizeof(text), "%06d", value);
  return text;
}

// a mask of the scene's camera size from a COCO RLE string, 0/255
cv::Mat Mask(const std::string& rle, const camera_info& camera) {
  cv::Mat mask = cv::Mat::zeros(camera.height, camera.width, CV_8UC1);
  DecodeRleInto(rle, camera.height, camera.width, mask.data);
  return mask * 255;
}

// the box of a mask's pixels as bop_toolkit's misc.calc_2d_bbox: x, y, max - min for width and
// height; [-1, -1, -1, -1] without pixels
std::vector<int> ToolkitBox(const cv::Mat& mask) {
  if (cv::countNonZero(mask) == 0) return {-1, -1, -1, -1};
  const cv::Rect box = cv::boundingRect(mask);
  return {box.x, box.y, box.width - 1, box.height - 1};
}

bool SameImage(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

// the vertices, normals and faces of an ASCII PLY file as stackgen-bop writes it
struct Ply {
  std::vector<std::vector<float>> vertices;  // x y z nx ny nz
  std::vector<std::vector<int>> faces;
};

Ply ReadPly(const std::string& path) {
  std::istringstream in(ReadFile(path));
  std::string line, word;
  int vertices = 0, faces = 0;
  while (std::getline(in, line) && line != "end_header") {
    std::istringstream fields(line);
    fields >> word;
    if (word == "element") {
      fields >> word;
      (word == "vertex" ? vertices : faces) = std::stoi(line.substr(line.rfind(' ') + 1));
    }
  }
  Ply ply;
  for (int v = 0; v < vertices && std::getline(in, line); ++v) {
    std::istringstream fields(line);
    std::vector<float> values;
    for (std::string value; fields >> value;) values.push_back(std::strtof(value.c_str(), nullptr));
    ply.vertices.push_back(values);
  }
  for (int f = 0; f < faces && std::getline(in, line); ++f) {
    std::istringstream fields(line);
    std::vector<int> values;
    for (int value; fields >> value;) values.push_back(value);
    ply.faces.push_back(values);
  }
  return ply;
}

class BopPipelineTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir("stackgen-bop-e2e");
    cache_ = scratch_->path() + "/cache";
    reference_ = scratch_->path() + "/reference";
    const std::string url = testing::FreeMulticastUrl();
    Process bop(Bop(reference_, url), scratch_->path() + "/reference-bop");
    ASSERT_TRUE(bop.WaitForOutput("listening", 30)) << bop.Stderr();
    Process generator(Generator(url, cache_), scratch_->path() + "/reference-gen");
    ASSERT_EQ(generator.Wait(600), 0) << generator.Stderr();
    ASSERT_EQ(bop.Wait(60), 0) << bop.Stderr();
    summary_ = bop.Stdout();
  }
  static void TearDownTestSuite() { delete scratch_; }

  static testing::ScratchDir* scratch_;
  static std::string cache_;
  static std::string reference_;
  static std::string summary_;
};

testing::ScratchDir* BopPipelineTest::scratch_ = nullptr;
std::string BopPipelineTest::cache_;
std::string BopPipelineTest::reference_;
std::string BopPipelineTest::summary_;

// every field of the dataset equals what the scene messages and models say: camera, poses,
// boxes, pixel counts, visib_fract, depth and both masks bit for bit, the colour image byte for
// byte; distractors are no objects; the models' PLY and models_info agree with the meshes.
TEST_F(BopPipelineTest, DatasetMatchesTheScenes) {
  EXPECT_NE(summary_.find("wrote " + reference_ + ": " + std::to_string(kScenes) +
                          " images in 1 chunks of train_pbr"),
            std::string::npos)
      << summary_;
  const LoadedConfig config = LoadConfig(kConfig);
  SceneGenerator generator(config, 0, kSeed, cache_);
  const std::string chunk = reference_ + "/train_pbr/000000/";
  const json scene_camera = json::parse(ReadFile(chunk + "scene_camera.json"));
  const json scene_gt = json::parse(ReadFile(chunk + "scene_gt.json"));
  const json scene_gt_info = json::parse(ReadFile(chunk + "scene_gt_info.json"));
  const json coco = json::parse(ReadFile(chunk + "scene_gt_coco.json"));
  ASSERT_EQ(scene_gt.size(), static_cast<size_t>(kScenes));
  int coco_annotations = 0;
  for (int k = 0; k < kScenes; ++k) {
    SCOPED_TRACE("scene " + std::to_string(k));
    const scene message = generator.Generate(k, nullptr);
    const camera_info& camera = message.camera;
    const std::string id = std::to_string(k);

    // the camera: K, world to camera (the inverse of world_from_camera), depth scale
    const json& cam = scene_camera.at(id);
    EXPECT_EQ(cam["cam_K"],
              json({camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0}));
    EXPECT_EQ(cam["depth_scale"], camera.depth_scale_mm);
    const double* r = camera.world_from_camera.rotation;
    const double* t = camera.world_from_camera.translation_mm;
    for (int i = 0; i < 3; ++i) {
      double origin = cam["cam_t_w2c"][i].get<double>();
      for (int j = 0; j < 3; ++j) {
        EXPECT_NEAR(cam["cam_R_w2c"][i * 3 + j].get<double>(), r[j * 3 + i], 1e-12);
        origin += r[j * 3 + i] * t[j];
      }
      EXPECT_NEAR(origin, 0.0, 1e-9) << "R_w2c * t_wfc + t_w2c is not the camera's origin";
    }

    // depth: the same uint16 values, so depth_mm = value * depth_scale within depth_scale
    std::string why;
    const cv::Mat depth = cv::imread(chunk + "depth/" + Six(k) + ".png", cv::IMREAD_UNCHANGED);
    const cv::Mat sent = cv::imdecode(message.depth.data, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(depth.type(), CV_16UC1);
    EXPECT_TRUE(SameImage(depth, sent));
    EXPECT_EQ(ReadFile(chunk + "rgb/" + Six(k) + ".png"),
              std::string(message.color.data.begin(), message.color.data.end()));

    // one ground truth per instance, by instance id; distractors are none
    std::vector<const instance*> objects;
    for (const instance& object : message.instances) objects.push_back(&object);
    std::sort(objects.begin(), objects.end(),
              [](const instance* a, const instance* b) { return a->instance_id < b->instance_id; });
    ASSERT_EQ(scene_gt.at(id).size(), objects.size());
    ASSERT_EQ(scene_gt_info.at(id).size(), objects.size());
    for (size_t g = 0; g < objects.size(); ++g) {
      const instance& object = *objects[g];
      SCOPED_TRACE("gt " + std::to_string(g));
      const json& gt = scene_gt.at(id)[g];
      EXPECT_TRUE(object.class_id == 1 || object.class_id == 2) << object.class_id;
      EXPECT_EQ(gt["obj_id"], object.class_id);
      EXPECT_EQ(gt["cam_R_m2c"], std::vector<double>(object.camera_from_object.rotation,
                                                     object.camera_from_object.rotation + 9));
      EXPECT_EQ(gt["cam_t_m2c"], std::vector<double>(object.camera_from_object.translation_mm,
                                                     object.camera_from_object.translation_mm + 3));
      const json& info = scene_gt_info.at(id)[g];
      EXPECT_EQ(info["px_count_all"], object.px_count_all);
      EXPECT_EQ(info["px_count_visib"], object.px_count_visib);
      EXPECT_EQ(info["visib_fract"], object.visib_fract);
      // the masks, bit for bit; px_count_valid: full-mask pixels with a depth
      const std::string name = Six(k) + "_" + Six(static_cast<int>(g)) + ".png";
      const cv::Mat full = Mask(object.mask_obj_rle, camera);
      const cv::Mat visible = Mask(object.mask_visib_rle, camera);
      // boxes as the toolkit's misc.calc_2d_bbox gives them for the mask's pixels
      // (calc_gt_info.py: no box of the object either when none of it is visible)
      const std::vector<int> no_box = {-1, -1, -1, -1};
      EXPECT_EQ(info["bbox_obj"], object.px_count_visib > 0 ? ToolkitBox(full) : no_box);
      EXPECT_EQ(info["bbox_visib"], ToolkitBox(visible));
      EXPECT_TRUE(SameImage(cv::imread(chunk + "mask/" + name, cv::IMREAD_UNCHANGED), full));
      EXPECT_TRUE(
          SameImage(cv::imread(chunk + "mask_visib/" + name, cv::IMREAD_UNCHANGED), visible));
      EXPECT_EQ(info["px_count_valid"], cv::countNonZero(full & (sent > 0)));
      if (object.px_count_visib > 0) ++coco_annotations;
    }
  }

  // scene_gt_coco.json: an annotation per ground truth with visible pixels, images that exist
  EXPECT_EQ(coco["annotations"].size(), static_cast<size_t>(coco_annotations));
  ASSERT_EQ(coco["images"].size(), static_cast<size_t>(kScenes));
  for (const json& image : coco["images"]) {
    EXPECT_TRUE(fs::exists(chunk + image["file_name"].get<std::string>())) << image;
  }
  // the toolkit's layout: '{', one '  "KEY": VALUE' line per image, '}'
  const std::string text = ReadFile(chunk + "scene_gt.json");
  EXPECT_EQ(text.substr(0, 9), "{\n  \"0\": ");
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), kScenes + 1);

  // the camera of the dataset, and the models of both classes
  const json camera_file = json::parse(ReadFile(reference_ + "/camera.json"));
  const camera_info& camera = generator.Generate(0, nullptr).camera;
  EXPECT_EQ(camera_file, json({{"cx", camera.cx},
                               {"cy", camera.cy},
                               {"depth_scale", camera.depth_scale_mm},
                               {"fx", camera.fx},
                               {"fy", camera.fy},
                               {"height", camera.height},
                               {"width", camera.width}}));
  const json models_info = json::parse(ReadFile(reference_ + "/models/models_info.json"));
  ASSERT_EQ(generator.Models().size(), 2u);
  ASSERT_EQ(models_info.size(), 2u);
  for (const model& expected : generator.Models()) {
    SCOPED_TRACE("model " + std::to_string(expected.class_id));
    // the PLY holds the mesh file's vertices (mm), normals and triangles, every float exact
    const Ply ply = ReadPly(reference_ + "/models/obj_" + Six(expected.class_id) + ".ply");
    const TriangleMesh mesh = LoadMesh(config.Resolve(expected.mesh), 1.0);
    ASSERT_EQ(ply.vertices.size(), mesh.positions_mm.size());
    ASSERT_EQ(ply.faces.size(), mesh.triangles.size());
    double low[3] = {1e300, 1e300, 1e300}, high[3] = {-1e300, -1e300, -1e300}, diameter = 0;
    for (size_t v = 0; v < ply.vertices.size(); ++v) {
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(ply.vertices[v][a], mesh.positions_mm[v][a]);
        EXPECT_EQ(ply.vertices[v][3 + a], mesh.normals[v][a]);
        low[a] = std::min(low[a], double{mesh.positions_mm[v][a]});
        high[a] = std::max(high[a], double{mesh.positions_mm[v][a]});
      }
      for (size_t w = 0; w < v; ++w) {
        diameter = std::max(
            diameter, double((mesh.positions_mm[v] - mesh.positions_mm[w]).cast<double>().norm()));
      }
    }
    for (size_t f = 0; f < ply.faces.size(); ++f) {
      EXPECT_EQ(ply.faces[f], std::vector<int>({3, static_cast<int>(mesh.triangles[f][0]),
                                                static_cast<int>(mesh.triangles[f][1]),
                                                static_cast<int>(mesh.triangles[f][2])}));
    }
    // models_info: diameter (the largest vertex distance), bounding box, the symmetries found
    const json& info = models_info.at(std::to_string(expected.class_id));
    EXPECT_NEAR(info["diameter"].get<double>(), diameter, 1e-9);
    const char* axes = "xyz";
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(info[std::string("min_") + axes[a]], low[a]);
      EXPECT_EQ(info[std::string("size_") + axes[a]], high[a] - low[a]);
    }
    EXPECT_EQ(info.value("symmetries_discrete", json::array()), json(expected.discrete_symmetries));
  }
  // the dowel pin (class 2) is round: a continuous symmetry about its long axis (x)
  const json& pin = models_info.at("2");
  ASSERT_EQ(pin["symmetries_continuous"].size(), 1u);
  EXPECT_NEAR(std::abs(pin["symmetries_continuous"][0]["axis"][0].get<double>()), 1.0, 1e-6);
}

// what `tar` says of a shard: its member names (-t), or one member's bytes (-xO)
std::string Tar(const std::vector<std::string>& args) {
  const std::string tar = testing::FindOnPath("tar");
  std::string out, err;
  EXPECT_EQ(
      testing::RunToEnd(tar, args, testing::MakeTempDir("stackgen-tar") + "/tar", &out, &err, 60),
      0)
      << err;
  return out;
}

// the webdataset shards hold every image once, under one key with its seven members (image,
// depth, camera, gt, gt_info and both masks, the same records as the scenewise files), and
// key_to_shard.json names the shard of every key.
TEST_F(BopPipelineTest, ShardsHoldEverySceneOnce) {
  const std::string shards = reference_ + "/shards/";
  const json key_to_shard = json::parse(ReadFile(shards + "key_to_shard.json"));
  ASSERT_EQ(key_to_shard.size(), static_cast<size_t>(kScenes));
  const json scene_gt = json::parse(ReadFile(reference_ + "/train_pbr/000000/scene_gt.json"));
  std::map<std::string, int> members_per_key;
  int shard_files = 0;
  for (const auto& entry : fs::directory_iterator(shards)) {
    const std::string name = entry.path().filename().string();
    if (entry.path().extension() != ".tar") continue;
    ++shard_files;
    const int shard_id = std::stoi(name.substr(6, 6));  // shard-NNNNNN.tar
    std::istringstream members(Tar({"-tf", entry.path().string()}));
    for (std::string member; std::getline(members, member);) {
      const std::string key = member.substr(0, member.find('.'));
      ++members_per_key[key];
      EXPECT_EQ(key_to_shard.at(key), shard_id) << member << " is in " << name;
    }
  }
  // images 0..3 in shard 0, 4 and 5 in shard 1 (SCENE_ID * 250 + IM_ID / 4)
  EXPECT_EQ(shard_files, 2);
  ASSERT_EQ(members_per_key.size(), static_cast<size_t>(kScenes));
  for (int k = 0; k < kScenes; ++k) {
    const std::string key = "000000_" + Six(k);
    EXPECT_EQ(members_per_key[key], 7) << key;
    const std::string shard = shards + "shard-" + Six(k / 4) + ".tar";
    // the same records and pixels as the scenewise files
    EXPECT_EQ(json::parse(Tar({"-xOf", shard, key + ".gt.json"})), scene_gt.at(std::to_string(k)));
    EXPECT_EQ(Tar({"-xOf", shard, key + ".rgb.png"}),
              ReadFile(reference_ + "/train_pbr/000000/rgb/" + Six(k) + ".png"));
    const json masks = json::parse(Tar({"-xOf", shard, key + ".mask_visib.json"}));
    ASSERT_EQ(masks.size(), scene_gt.at(std::to_string(k)).size());
    for (const auto& [gt_id, rle] : masks.items()) {
      // uncompressed runs, column-major from the zeros, as pycoco_utils.binary_mask_to_rle
      const cv::Mat png = cv::imread(reference_ + "/train_pbr/000000/mask_visib/" + Six(k) + "_" +
                                         Six(std::stoi(gt_id)) + ".png",
                                     cv::IMREAD_UNCHANGED);
      ASSERT_EQ(rle["size"], json({png.rows, png.cols}));
      cv::Mat decoded = cv::Mat::zeros(png.cols, png.rows, CV_8UC1);  // transposed: column-major
      size_t at = 0;
      bool ones = false;
      for (const json& run : rle["counts"]) {
        const size_t length = run.get<size_t>();
        if (ones) decoded.reshape(1, 1).colRange(at, at + length).setTo(255);
        at += length;
        ones = !ones;
      }
      EXPECT_EQ(at, static_cast<size_t>(png.total()));
      EXPECT_TRUE(SameImage(decoded.t(), png)) << key << " gt " << gt_id;
    }
  }
}

// kill -9 of the writer mid-run, then the same writer again with --resume: the same files as
// the plain run's, byte for byte (the journal aside), shards and their index included.
TEST_F(BopPipelineTest, KilledAndResumedGivesTheSameFiles) {
  const std::string url = testing::FreeMulticastUrl();
  const std::string out = scratch_->path() + "/killed";
  auto bop = std::make_unique<Process>(Bop(out, url), out + "-bop1");
  ASSERT_TRUE(bop->WaitForOutput("listening", 30)) << bop->Stderr();
  Process generator(Generator(url, cache_), out + "-gen");
  for (int i = 0; i < 30000 && ImagesStored(out) < 2; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_GE(ImagesStored(out), 2);
  bop->Signal(SIGKILL);
  EXPECT_EQ(bop->Wait(10), 128 + SIGKILL);
  EXPECT_LT(ImagesStored(out), kScenes) << "killed too late to test a resume";

  Process resumed(Bop(out, url, {"--resume"}), out + "-bop2");
  ASSERT_EQ(resumed.Wait(600), 0) << resumed.Stderr();
  EXPECT_NE(resumed.Stdout().find("resumed"), std::string::npos) << resumed.Stdout();
  ASSERT_EQ(generator.Wait(120), 0) << generator.Stderr();

  const auto expected = testing::DatasetFiles(reference_, "bop.journal"),
             actual = testing::DatasetFiles(out, "bop.journal");
  EXPECT_EQ(expected.size(), actual.size());
  for (const auto& [path, bytes] : expected) {
    const auto found = actual.find(path);
    ASSERT_NE(found, actual.end()) << path << " is missing after the resume";
    EXPECT_TRUE(found->second == bytes) << path << " differs from the plain run's";
  }
}

}  // namespace
}  // namespace stackgen
