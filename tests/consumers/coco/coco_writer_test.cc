#include "consumers/coco/coco_writer.h"

#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "contract/scene_contract.h"
#include "tests/consumers/coco/coco_test_scenes.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::SceneA;
using testing::SceneB;
using testing::SceneC;

json ReadDataset(const std::string& dir) {
  std::ifstream file(dir + "/annotations.json");
  return json::parse(file);
}

// the text of the InvalidSceneError that Add throws, or "" if it does not throw
std::string AddError(CocoWriter& writer, const stackgen::scene& scene) {
  try {
    writer.Add(scene);
  } catch (const InvalidSceneError& error) {
    return error.what();
  }
  return "";
}

// no file under `dir` is a temporary one
void ExpectNoTemporaryFiles(const std::string& dir) {
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    EXPECT_EQ(name.find(".tmp"), std::string::npos) << entry.path();
  }
}

// the text of annotations.json in `dir` without its info line (which holds the date)
// the bytes of a dataset's annotations.json
std::string DatasetBytes(const std::string& dir) {
  return testing::ReadFile(dir + "/annotations.json");
}

// the message of the std::runtime_error that `body` throws, or "" if it does not throw
std::string RuntimeError(const std::function<void()>& body) {
  try {
    body();
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "";
}

// a scene of generator `generator_id` with no instances and a `size` x `size` PNG of noise,
// which does not compress: about 3 * size * size bytes
stackgen::scene NoiseScene(int generator_id, int64_t seq, int size) {
  stackgen::scene scene = testing::MakeScene(generator_id, seq, {});
  cv::Mat noise(size, size, CV_8UC3);
  cv::randu(noise, cv::Scalar::all(0), cv::Scalar::all(256));
  std::vector<uint8_t> png;
  cv::imencode(".png", noise, png);
  scene.camera.width = scene.camera.height = size;
  scene.color.width = scene.color.height = size;
  scene.color.encoding = stackgen::image::ENCODING_PNG;
  scene.color.data = png;
  scene.color.size = static_cast<int32_t>(png.size());
  return scene;
}

// the end offsets (after the '\n') of the lines of the file `path`
std::vector<uint64_t> LineEnds(const std::string& path) {
  const std::string text = testing::ReadFile(path);
  std::vector<uint64_t> ends;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '\n') ends.push_back(i + 1);
  }
  return ends;
}

// the amodal fields of `annotation` (over an 8 x 6 image) agree with each other: the full mask
// decodes to px_count_all pixels inside amodal_bbox = bbox_obj, and holds the visible mask
void ExpectAmodalFields(const json& annotation) {
  const json& amodal = annotation["amodal_segmentation"];
  ASSERT_TRUE(amodal.is_object()) << annotation.dump();
  EXPECT_EQ(amodal["size"], json::parse("[6, 8]"));
  const cv::Mat full = DecodeRle(amodal["counts"].get<std::string>(), 6, 8);
  EXPECT_EQ(cv::countNonZero(full), annotation["px_count_all"].get<int>()) << annotation.dump();
  EXPECT_EQ(annotation["amodal_bbox"], annotation["bbox_obj"]);
  const std::array<int, 4> box = RleBbox(amodal["counts"].get<std::string>(), 6, 8);
  EXPECT_EQ(annotation["amodal_bbox"], json(box)) << annotation.dump();
  const cv::Mat visible = DecodeRle(annotation["segmentation"]["counts"].get<std::string>(), 6, 8);
  EXPECT_EQ(cv::countNonZero(visible & ~full), 0) << "visible pixels outside the full mask";
}

// Three scenes (RAW RGB, PNG, RAW gray) give the expected images, categories and annotations.
TEST(CocoWriterTest, WritesDataset) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path() + "/out";
  auto writer = std::make_unique<CocoWriter>(dir);
  EXPECT_TRUE(writer->Add(SceneA()));
  EXPECT_TRUE(writer->Add(SceneB()));
  EXPECT_TRUE(writer->Add(SceneC()));
  EXPECT_FALSE(fs::exists(dir + "/annotations.json")) << "written before Finish";
  writer->Finish();
  EXPECT_EQ(writer->num_images(), 3);
  EXPECT_EQ(writer->num_annotations(), 4);
  EXPECT_EQ(writer->num_crowd(), 0);
  EXPECT_EQ(writer->num_dropped(), 1);
  EXPECT_EQ(writer->num_lost(), 0);

  const json dataset = ReadDataset(dir);
  // no wall-clock time: the same scenes give the same bytes
  EXPECT_FALSE(dataset["info"].contains("date_created"));
  EXPECT_FALSE(dataset["info"].contains("year"));
  EXPECT_EQ(dataset["licenses"], json::array());

  // images: ids generator_id * 1e8 + seq + 1, sorted, with their files
  const json& images = dataset["images"];
  ASSERT_EQ(images.size(), 3u);
  EXPECT_EQ(images[0]["id"], 1);
  EXPECT_EQ(images[1]["id"], 2);
  EXPECT_EQ(images[2]["id"], 100000001);
  EXPECT_EQ(images[0]["file_name"], "0_000000.png");
  EXPECT_EQ(images[1]["file_name"], "0_000001.png");
  EXPECT_EQ(images[2]["file_name"], "1_000000.png");
  EXPECT_EQ(images[2]["stackgen"]["generator_id"], 1);
  EXPECT_EQ(images[1]["stackgen"]["seq"], 1);
  EXPECT_EQ(images[1]["stackgen"]["seed"], 1);
  EXPECT_EQ(images[0]["stackgen"]["camera"]["fx"], 500.0);
  EXPECT_EQ(images[0]["stackgen"]["camera"]["depth_scale_mm"], 0.1);
  EXPECT_EQ(images[0]["stackgen"]["camera"]["world_from_camera"]["translation_mm"][2], 500.0);
  for (const json& image : images) {
    EXPECT_EQ(image["width"], 8);
    EXPECT_EQ(image["height"], 6);
    const cv::Mat pixels =
        cv::imread(dir + "/images/" + image["file_name"].get<std::string>(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(pixels.empty()) << image["file_name"];
    EXPECT_EQ(pixels.cols, 8);
    EXPECT_EQ(pixels.rows, 6);
  }
  // RAW RGB lands as a colour PNG with R, G, B in place: pixel (x 3, y 2) = (30, 40, 0)
  const cv::Mat color = cv::imread(dir + "/images/0_000000.png", cv::IMREAD_UNCHANGED);
  ASSERT_EQ(color.type(), CV_8UC3);
  EXPECT_EQ(color.at<cv::Vec3b>(2, 3), cv::Vec3b(0, 40, 30));  // BGR in OpenCV
  // the PNG scene is written byte for byte
  const std::string png = testing::ReadFile(dir + "/images/0_000001.png");
  EXPECT_EQ(std::vector<uint8_t>(png.begin(), png.end()), SceneB().color.data);
  // RAW gray stays gray
  const cv::Mat gray = cv::imread(dir + "/images/1_000000.png", cv::IMREAD_UNCHANGED);
  EXPECT_EQ(gray.type(), CV_8UC1);
  EXPECT_EQ(gray.at<uint8_t>(5, 7), 77);

  // categories from the scenes
  EXPECT_EQ(dataset["categories"],
            json::parse(R"([{"id": 1, "name": "connector", "supercategory": "part"},
                            {"id": 2, "name": "bolt", "supercategory": "part"}])"));

  // annotations: ids image_id * 1000 + instance_id; instance 2 of scene A is not annotated
  const json& annotations = dataset["annotations"];
  ASSERT_EQ(annotations.size(), 4u);
  std::vector<int64_t> ids;
  for (const json& annotation : annotations) ids.push_back(annotation["id"].get<int64_t>());
  EXPECT_EQ(ids, (std::vector<int64_t>{1001, 1003, 2001, 100000001007}));
  const json& first = annotations[0];
  EXPECT_EQ(first["image_id"], 1);
  EXPECT_EQ(first["category_id"], 1);
  EXPECT_EQ(first["bbox"], json::parse("[1, 2, 3, 3]"));
  EXPECT_EQ(first["area"], 9);
  EXPECT_EQ(first["iscrowd"], 0);
  EXPECT_EQ(first["segmentation"]["size"], json::parse("[6, 8]"));
  EXPECT_EQ(first["segmentation"]["counts"], EncodeRle([] {
              cv::Mat mask = cv::Mat::zeros(6, 8, CV_8UC1);
              mask(cv::Rect(1, 2, 3, 3)).setTo(1);
              return mask;
            }()));
  EXPECT_EQ(first["instance_id"], 1);
  EXPECT_EQ(first["visib_fract"], 1.0);
  EXPECT_EQ(first["px_count_all"], 9);
  EXPECT_EQ(first["px_count_visib"], 9);
  EXPECT_EQ(first["bbox_obj"], json::parse("[1, 2, 3, 3]"));
  EXPECT_EQ(first["amodal_bbox"], json::parse("[1, 2, 3, 3]"));
  EXPECT_EQ(first["amodal_segmentation"]["counts"], first["segmentation"]["counts"]);
  EXPECT_EQ(first["posture_deg"], json::parse("[10.0, 0.0, 0.0]"));
  EXPECT_EQ(first["cam_R_m2c"], json::parse("[1, 0, 0, 0, 1, 0, 0, 0, 1]"));
  EXPECT_EQ(first["cam_t_m2c"], json::parse("[0, 0, 401]"));
  EXPECT_EQ(first["world_t_m2w"][0], 0.1);
  EXPECT_EQ(first["world_R_m2w"].size(), 9u);
  const json& bolt = annotations[1];
  EXPECT_EQ(bolt["category_id"], 2);
  EXPECT_EQ(bolt["visib_fract"], 0.5);
  EXPECT_EQ(bolt["px_count_all"], 12);
  EXPECT_EQ(bolt["bbox"], json::parse("[5, 0, 3, 2]"));
  EXPECT_EQ(bolt["amodal_bbox"], json::parse("[0, 0, 8, 6]"));
  EXPECT_EQ(bolt["iscrowd"], 0);
  // exactly at the threshold is kept
  EXPECT_EQ(annotations[3]["visib_fract"], 0.3);
  for (const json& annotation : annotations) {
    const cv::Mat mask = DecodeRle(annotation["segmentation"]["counts"].get<std::string>(), 6, 8);
    EXPECT_EQ(cv::countNonZero(mask), annotation["area"].get<int>());
    ExpectAmodalFields(annotation);
  }

  // one image and one annotation per line, as a reader that diffs datasets expects
  std::istringstream text(testing::ReadFile(dir + "/annotations.json"));
  int image_lines = 0, annotation_lines = 0;
  for (std::string line; std::getline(text, line);) {
    image_lines += line.rfind("{\"file_name\":", 0) == 0;
    annotation_lines += line.rfind("{\"amodal_bbox\":", 0) == 0;
  }
  EXPECT_EQ(image_lines, 3);
  EXPECT_EQ(annotation_lines, 4);

  // nothing temporary is left once the writer is gone; the journal stays
  writer.reset();
  ExpectNoTemporaryFiles(dir);
  EXPECT_TRUE(fs::exists(dir + "/annotations.journal"));
}

// a repeat of a stored scene is not stored again; the same ids with another seed (another run
// with the same generator id) are refused, naming the scene and the seed, and nothing changes.
TEST(CocoWriterTest, RepeatWithAnotherSeedIsRefused) {
  const testing::ScopedTempDir scratch("coco-writer");
  CocoWriter writer(scratch.path() + "/d");
  stackgen::scene scene = testing::SceneA();
  ASSERT_TRUE(writer.Add(scene));
  EXPECT_FALSE(writer.Add(scene));
  scene.header.seed += 1;
  try {
    writer.Add(scene);
    FAIL() << "a repeat with another seed was accepted";
  } catch (const InvalidSceneError& error) {
    EXPECT_NE(std::string(error.what()).find("scene 0/0"), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("seed"), std::string::npos) << error.what();
  }
  EXPECT_EQ(writer.num_images(), 1);
  // ids outside the layout are refused before any id is computed from them
  scene.header.seq = -5;
  EXPECT_THROW(writer.Add(scene), InvalidSceneError);
}

// what `tar` says of a shard: its member names (-t), or one member's bytes (-xO)
std::string Tar(const std::vector<std::string>& args) {
  std::string out, err;
  EXPECT_EQ(testing::RunToEnd(testing::FindOnPath("tar"), args,
                              testing::MakeTempDir("coco-tar") + "/tar", &out, &err, 60),
            0)
      << err;
  return out;
}

// With shards of 2 images, five scenes of generator 0 (added out of order) and one of
// generator 1 go to shards by seq, each once, under its key with its image and records; the
// index names every key's shard; a full shard is written at its commit, the rest by Finish.
TEST(CocoWriterTest, ShardsHoldEverySceneOnce) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path() + "/d";
  CocoWriterOptions options;
  options.shard_images = 2;
  CocoWriter writer(dir, options);
  const auto connector = [](int id) {
    return testing::MakeInstance(id, 1, "connector", cv::Rect(0, 0, 2 + id, 2), 1.0);
  };
  for (const int64_t seq : {1, 0, 4, 3})
    ASSERT_TRUE(writer.Add(testing::MakeScene(0, seq, {connector(1)})));
  // shard 0 (seqs 0 and 1) is full; shard 1 waits for seq 2
  EXPECT_TRUE(std::filesystem::exists(dir + "/shards/shard-000000.tar"));
  EXPECT_FALSE(std::filesystem::exists(dir + "/shards/shard-000001.tar"));
  ASSERT_TRUE(writer.Add(testing::MakeScene(0, 2, {connector(2)})));
  ASSERT_TRUE(writer.Add(testing::MakeScene(1, 0, {connector(1)})));
  writer.Finish();

  // shards: generator 0 chunk 0 has 500 per chunk: 0 {0,1}, 1 {2,3}, 2 {4}; generator 1 chunk
  // 1000000: shard 500000000
  const json index = json::parse(testing::ReadFile(dir + "/shards/key_to_shard.json"));
  EXPECT_EQ(index, json({{"0_000000", 0},
                         {"0_000001", 0},
                         {"0_000002", 1},
                         {"0_000003", 1},
                         {"0_000004", 2},
                         {"1_000000", 500000000}}));
  const json annotations = json::parse(testing::ReadFile(dir + "/annotations.json"));
  std::map<std::string, int> keys;
  for (const auto& [key, shard] : index.items()) {
    char name[64];
    std::snprintf(name, sizeof(name), "%s/shards/shard-%06lld.tar", dir.c_str(),
                  static_cast<long long>(shard.get<int64_t>()));
    std::istringstream members(Tar({"-tf", name}));
    for (std::string member; std::getline(members, member);) {
      if (member.rfind(key + ".", 0) == 0) ++keys[key];
    }
    // the image as images/ holds it, the records as annotations.json has them
    EXPECT_EQ(Tar({"-xOf", name, key + ".png"}),
              testing::ReadFile(dir + "/images/" + key + ".png"));
    const json records = json::parse(Tar({"-xOf", name, key + ".json"}));
    bool found = false;
    for (const json& image : annotations["images"]) {
      if (image["file_name"] != key + ".png") continue;
      found = true;
      EXPECT_EQ(records["image"], image);
      json expected = json::array();
      for (const json& annotation : annotations["annotations"]) {
        if (annotation["image_id"] == image["id"]) expected.push_back(annotation);
      }
      EXPECT_EQ(records["annotations"], expected) << key;
    }
    EXPECT_TRUE(found) << key;
  }
  EXPECT_EQ(keys.size(), 6u);
  for (const auto& [key, count] : keys) EXPECT_EQ(count, 2) << key << ": an image and its JSON";
}

// A JPEG scene is written as .jpg, its bytes as they came.
TEST(CocoWriterTest, JpegWrittenAsIs) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);
  const stackgen::scene scene = testing::MakeScene(
      2, 5, {testing::MakeInstance(1, 1, "connector", cv::Rect(0, 0, 2, 2), 1.0)},
      stackgen::image::ENCODING_JPEG);
  writer.Add(scene);
  writer.Finish();
  EXPECT_EQ(ReadDataset(dir)["images"][0]["file_name"], "2_000005.jpg");
  const std::string jpeg = testing::ReadFile(dir + "/images/2_000005.jpg");
  EXPECT_EQ(std::vector<uint8_t>(jpeg.begin(), jpeg.end()), scene.color.data);
}

// An image that does not decode whole is refused before anything is written: a PNG with one
// bit flipped in its pixel data or cut in half, a JPEG cut short (libjpeg would fill it with
// grey); the intact scenes are stored.
TEST(CocoWriterTest, DamagedImagesAreRefused) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);
  const stackgen::scene png = NoiseScene(0, 0, 64);
  ASSERT_EQ(png.color.encoding, stackgen::image::ENCODING_PNG);
  stackgen::scene flipped = png;
  flipped.color.data[flipped.color.data.size() / 2] ^= 0x10;
  stackgen::scene cut = png;
  cut.color.data.resize(cut.color.data.size() / 2);
  cut.color.size = static_cast<int32_t>(cut.color.data.size());
  stackgen::scene jpeg = testing::MakeScene(
      0, 1, {testing::MakeInstance(1, 1, "connector", cv::Rect(0, 0, 2, 2), 1.0)},
      stackgen::image::ENCODING_JPEG);
  stackgen::scene cut_jpeg = jpeg;
  cut_jpeg.color.data.resize(cut_jpeg.color.data.size() - 8);
  cut_jpeg.color.size = static_cast<int32_t>(cut_jpeg.color.data.size());
  for (const stackgen::scene* damaged : {&flipped, &cut, &cut_jpeg}) {
    const std::string error = AddError(writer, *damaged);
    EXPECT_NE(error.find("color.data does not decode as a whole"), std::string::npos) << error;
  }
  EXPECT_TRUE(fs::is_empty(dir + "/images"));
  EXPECT_TRUE(writer.Add(png));
  EXPECT_TRUE(writer.Add(jpeg));
  EXPECT_EQ(writer.num_images(), 2);
}

// A scene that disagrees with itself throws, naming the field, and writes nothing.
TEST(CocoWriterTest, InconsistentScenesThrowNamingTheField) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);

  stackgen::scene scene = SceneA();
  scene.color.width = 9;
  EXPECT_NE(AddError(writer, scene).find("color.width"), std::string::npos);

  scene = SceneA();
  scene.color.data.pop_back();
  scene.color.size -= 1;
  EXPECT_NE(AddError(writer, scene).find("color.size"), std::string::npos);

  scene = SceneA();
  scene.color.size += 1;
  EXPECT_NE(AddError(writer, scene).find("color.size"), std::string::npos);

  scene = SceneB();  // a PNG of 8 x 6 said to be 8 x 5
  scene.camera.height = scene.color.height = 5;
  EXPECT_NE(AddError(writer, scene).find("color.data"), std::string::npos);

  scene = SceneB();
  scene.color.data[1] = 'X';  // not a PNG any more
  EXPECT_NE(AddError(writer, scene).find("color.data"), std::string::npos);

  scene = SceneA();
  scene.num_instances = 2;
  EXPECT_NE(AddError(writer, scene).find("num_instances"), std::string::npos);
  scene = SceneA();
  scene.instances[0].bbox_obj[2] = 2 * scene.camera.width + 1;  // more than an image past it
  EXPECT_NE(AddError(writer, scene).find("instances[0].bbox_obj"), std::string::npos);
  scene = SceneA();
  scene.instances[0].bbox_visib[1] = -1;
  EXPECT_NE(AddError(writer, scene).find("instances[0].bbox_visib"), std::string::npos);

  scene = SceneA();
  scene.instances[1].px_count_visib = 8;
  const std::string rle_error = AddError(writer, scene);
  EXPECT_NE(rle_error.find("instances[1].mask_visib_rle"), std::string::npos) << rle_error;
  EXPECT_NE(rle_error.find("scene 0/0"), std::string::npos) << rle_error;

  scene = SceneA();
  scene.instances[0].mask_visib_rle = "1p";
  EXPECT_NE(AddError(writer, scene).find("instances[0].mask_visib_rle"), std::string::npos);

  // the full mask like the visible one: its pixel count, its size, its form, present at all
  scene = SceneA();
  scene.instances[1].px_count_all = 10;
  const std::string obj_error = AddError(writer, scene);
  EXPECT_NE(obj_error.find("instances[1].mask_obj_rle holds 9 pixels, px_count_all is 10"),
            std::string::npos)
      << obj_error;

  scene = SceneA();
  scene.instances[0].mask_obj_rle = scene.instances[1].mask_obj_rle + "1";
  EXPECT_NE(AddError(writer, scene).find("instances[0].mask_obj_rle covers"), std::string::npos);

  scene = SceneA();
  scene.instances[2].mask_obj_rle = "1p";
  EXPECT_NE(AddError(writer, scene).find("instances[2].mask_obj_rle is not a COCO RLE"),
            std::string::npos);

  scene = SceneA();
  scene.instances[0].mask_obj_rle.clear();
  EXPECT_NE(AddError(writer, scene).find("instances[0].mask_obj_rle is empty"), std::string::npos);

  // an instance is annotated, ignored or neither, and a label needs visible pixels
  scene = SceneA();
  scene.instances[0].ignored = true;
  const std::string both_error = AddError(writer, scene);
  EXPECT_NE(both_error.find("instances[0].ignored and instances[0].annotated are both true"),
            std::string::npos)
      << both_error;

  scene = testing::SceneD();
  scene.instances[2].ignored = true;  // nothing of it is visible
  EXPECT_NE(AddError(writer, scene).find("instances[2].ignored is true but px_count_visib is 0"),
            std::string::npos);

  scene = SceneA();
  scene.instances[0].instance_id = 1;  // same as instances[1]
  EXPECT_NE(AddError(writer, scene).find("instance_id"), std::string::npos);

  scene = SceneA();
  scene.instances[0].instance_id = 1000;
  EXPECT_NE(AddError(writer, scene).find("instances[0].instance_id"), std::string::npos);

  scene = SceneA();
  scene.instances[2].class_name = "nut";  // class 1 is "connector" in instances[1]
  EXPECT_NE(AddError(writer, scene).find("instances[2].class_name"), std::string::npos);

  scene = SceneA();
  scene.instances[0].posture_deg[1] = NAN;
  EXPECT_NE(AddError(writer, scene).find("instances[0].posture_deg[1]"), std::string::npos);

  scene = SceneA();
  scene.color.encoding = 9;
  EXPECT_NE(AddError(writer, scene).find("color.encoding"), std::string::npos);

  // none of them left a trace; the good scene still goes in
  EXPECT_EQ(writer.num_images(), 0);
  EXPECT_TRUE(fs::is_empty(dir + "/images"));
  EXPECT_TRUE(writer.Add(SceneA()));
  // and a later scene may not rename a class
  scene = SceneB();
  scene.instances[0].class_name = "nut";
  EXPECT_NE(AddError(writer, scene).find("instances[0].class_name"), std::string::npos);
}

// The generator's labels decide: annotated -> iscrowd 0, ignored -> iscrowd 1 with the visible
// mask, area and box, neither -> nothing; both carry the amodal fields.
TEST(CocoWriterTest, IgnoredInstancesAreCrowdRegions) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);
  ASSERT_TRUE(writer.Add(testing::SceneD()));
  writer.Finish();
  EXPECT_EQ(writer.num_annotations(), 1);
  EXPECT_EQ(writer.num_crowd(), 1);
  EXPECT_EQ(writer.num_dropped(), 1);

  const json annotations = ReadDataset(dir)["annotations"];
  ASSERT_EQ(annotations.size(), 2u);
  const json& annotated = annotations[0];
  EXPECT_EQ(annotated["id"], 200000001001);
  EXPECT_EQ(annotated["iscrowd"], 0);
  EXPECT_EQ(annotated["px_count_all"], 10);
  const json& crowd = annotations[1];
  EXPECT_EQ(crowd["id"], 200000001002);
  EXPECT_EQ(crowd["iscrowd"], 1);
  EXPECT_EQ(crowd["category_id"], 1);
  EXPECT_EQ(crowd["area"], 4);
  EXPECT_EQ(crowd["px_count_visib"], 4);
  EXPECT_EQ(crowd["bbox"], json::parse("[5, 3, 2, 2]"));
  EXPECT_EQ(crowd["visib_fract"], 0.2);
  EXPECT_EQ(crowd["px_count_all"], 20);
  EXPECT_EQ(crowd["segmentation"]["counts"], testing::SceneD().instances[1].mask_visib_rle);
  EXPECT_EQ(crowd["amodal_segmentation"]["counts"], testing::SceneD().instances[1].mask_obj_rle);
  EXPECT_EQ(crowd["world_R_m2w"].size(), 9u);
  for (const json& annotation : annotations) ExpectAmodalFields(annotation);
}

// With polygons, an annotation's visible mask in two pieces, one with a hole, becomes two
// polygons through the boundary pixel centres; filled back (holes filled, as COCO polygons
// have none) they cover the mask and its hole exactly; a one-pixel piece is its square; ignore
// regions stay RLE; a dataset written without polygons is not resumed with them.
TEST(CocoWriterTest, PolygonsFillBackToTheMask) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  stackgen::scene scene = testing::SceneD();
  // instance 1: a ring (columns 0..3, rows 0..3, hole at 1..2 x 1..2), a bar (columns 5..7,
  // row 5) and one pixel (7, 1)
  cv::Mat mask = cv::Mat::zeros(testing::kSceneHeight, testing::kSceneWidth, CV_8UC1);
  mask(cv::Rect(0, 0, 4, 4)).setTo(255);
  mask(cv::Rect(1, 1, 2, 2)).setTo(0);
  mask(cv::Rect(5, 5, 3, 1)).setTo(255);
  mask.at<uint8_t>(1, 7) = 255;
  stackgen::instance& ring = scene.instances[0];
  ring.mask_visib_rle = EncodeRle(mask);
  ring.mask_obj_rle = EncodeRle(cv::Mat(mask.size(), CV_8UC1, cv::Scalar(255)));
  ring.px_count_visib = cv::countNonZero(mask);
  ring.px_count_all = mask.total();
  ring.visib_fract = static_cast<double>(ring.px_count_visib) / ring.px_count_all;
  const cv::Rect box = cv::boundingRect(mask);
  std::copy_n(std::array<int32_t, 4>{box.x, box.y, box.width, box.height}.data(), 4,
              ring.bbox_visib);
  std::copy_n(std::array<int32_t, 4>{0, 0, testing::kSceneWidth, testing::kSceneHeight}.data(), 4,
              ring.bbox_obj);
  CocoWriterOptions options;
  options.polygons = true;
  {
    CocoWriter writer(dir + "/polygons", options);
    ASSERT_TRUE(writer.Add(scene));
    writer.Finish();
  }
  const json annotations = ReadDataset(dir + "/polygons")["annotations"];
  ASSERT_EQ(annotations.size(), 2u);
  const json& polygons = annotations[0]["segmentation"];
  ASSERT_TRUE(polygons.is_array()) << polygons.dump();
  ASSERT_EQ(polygons.size(), 3u) << polygons.dump();
  // filled back: the centres' polygons shifted back to pixel indices, the squares' corners
  // drawn as their pixels
  cv::Mat filled = cv::Mat::zeros(mask.size(), CV_8UC1);
  for (const json& polygon : polygons) {
    const std::vector<double> values = polygon.get<std::vector<double>>();
    ASSERT_EQ(values.size() % 2, 0u);
    std::vector<cv::Point> points;
    const bool square = values.size() == 8 && values[0] == std::floor(values[0]);
    for (size_t k = 0; k < values.size(); k += 2) {
      points.emplace_back(static_cast<int>(std::lround(values[k] - 0.5)),
                          static_cast<int>(std::lround(values[k + 1] - 0.5)));
    }
    if (square) {
      filled(cv::Rect(static_cast<int>(values[0]), static_cast<int>(values[1]),
                      static_cast<int>(values[2] - values[0]),
                      static_cast<int>(values[5] - values[1])))
          .setTo(255);
    } else {
      cv::fillPoly(filled, std::vector<std::vector<cv::Point>>{points}, cv::Scalar(255));
    }
  }
  cv::Mat expected = mask.clone();
  expected(cv::Rect(1, 1, 2, 2)).setTo(255);  // the hole, filled
  EXPECT_EQ(cv::countNonZero(filled != expected), 0);
  EXPECT_TRUE(annotations[1]["segmentation"].is_object());  // the ignore region: RLE
  EXPECT_EQ(annotations[1]["iscrowd"], 1);

  // a dataset without polygons is not continued with them
  {
    CocoWriter writer(dir + "/rle");
    ASSERT_TRUE(writer.Add(testing::SceneD()));
  }
  options.resume = true;
  try {
    CocoWriter writer(dir + "/rle", options);
    FAIL() << "a resume with polygons continued an RLE dataset";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("written without --polygons"), std::string::npos)
        << error.what();
  }
}

// A min_visib_fract of the writer's own drops annotated instances below it, but brings back
// nothing the generator did not annotate and keeps ignore regions.
TEST(CocoWriterTest, OwnThresholdOnlyDropsMore) {
  const testing::ScopedTempDir scratch("coco-writer");
  const auto ids = [](const json& annotations) {
    std::vector<int64_t> result;
    for (const json& annotation : annotations) result.push_back(annotation["id"].get<int64_t>());
    return result;
  };
  {
    CocoWriterOptions options;
    options.min_visib_fract = 0.5;
    CocoWriter writer(scratch.path() + "/strict", options);
    for (const stackgen::scene& scene : {SceneA(), SceneC(), testing::SceneD()}) {
      writer.Add(scene);
    }
    writer.Finish();
    // scene A: 1 (1.0) and 3 (0.5) kept, 2 not annotated; scene C: 7 (0.3) below 0.5;
    // scene D: 1 (0.8) kept, 2 stays an ignore region, 3 not annotated
    EXPECT_EQ(ids(ReadDataset(scratch.path() + "/strict")["annotations"]),
              (std::vector<int64_t>{1001, 1003, 200000001001, 200000001002}));
    EXPECT_EQ(writer.num_annotations(), 3);
    EXPECT_EQ(writer.num_crowd(), 1);
    EXPECT_EQ(writer.num_dropped(), 3);
  }
  {
    CocoWriterOptions options;
    options.min_visib_fract = 0.0;
    CocoWriter writer(scratch.path() + "/zero", options);
    writer.Add(SceneA());
    writer.Finish();
    EXPECT_EQ(ids(ReadDataset(scratch.path() + "/zero")["annotations"]),
              (std::vector<int64_t>{1001, 1003}));
    EXPECT_EQ(writer.num_dropped(), 1);
  }
}

// A repeated (generator_id, seq) is stored once.
TEST(CocoWriterTest, DuplicateStoredOnce) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);
  EXPECT_TRUE(writer.Add(SceneA()));
  EXPECT_FALSE(writer.Add(SceneA()));
  writer.Finish();
  const json dataset = ReadDataset(dir);
  EXPECT_EQ(dataset["images"].size(), 1u);
  EXPECT_EQ(dataset["annotations"].size(), 2u);
  EXPECT_EQ(writer.num_annotations(), 2);
}

// Two writers fed the same scenes in different orders write the same annotations.json, byte for
// byte.
TEST(CocoWriterTest, ArrivalOrderDoesNotMatter) {
  const testing::ScopedTempDir scratch_a("coco-writer");
  const std::string dir_a = scratch_a.path();
  const testing::ScopedTempDir scratch_b("coco-writer");
  const std::string dir_b = scratch_b.path();
  {
    CocoWriter writer(dir_a);
    for (const stackgen::scene& scene : {SceneA(), SceneB(), SceneC()}) writer.Add(scene);
    writer.Finish();
  }
  {
    CocoWriter writer(dir_b);
    for (const stackgen::scene& scene : {SceneC(), SceneB(), SceneA(), SceneB()}) {
      writer.Add(scene);
    }
    writer.Finish();
  }
  EXPECT_EQ(DatasetBytes(dir_a), DatasetBytes(dir_b));
}

// A folder that holds a dataset is refused; an empty one, or a fresh one, is fine.
TEST(CocoWriterTest, RefusesToOverwrite) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  {
    CocoWriter writer(dir);
    writer.Finish();
  }
  const json empty = ReadDataset(dir);
  EXPECT_EQ(empty["images"], json::array());
  EXPECT_EQ(empty["annotations"], json::array());
  try {
    CocoWriter again(dir);
    FAIL() << "no throw";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("annotations.json"), std::string::npos);
  }
  fs::create_directory(dir + "/empty");
  EXPECT_NO_THROW(CocoWriter(dir + "/empty"));
  EXPECT_NO_THROW(CocoWriter(dir + "/new/deeper"));
  EXPECT_THROW(CocoWriter(dir + "/other", {1.5}), std::runtime_error);
}

// Seq gaps per generator count as lost; Finish may be called again after more scenes.
TEST(CocoWriterTest, CountsLostAndFinishesAgain) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  CocoWriter writer(dir);
  writer.Add(testing::MakeScene(0, 0, {}));
  writer.Add(testing::MakeScene(0, 3, {}));
  writer.Add(testing::MakeScene(4, 10, {}));
  writer.Finish();
  EXPECT_EQ(ReadDataset(dir)["images"].size(), 3u);
  EXPECT_EQ(writer.LostPerGenerator(), (std::map<int32_t, int64_t>{{0, 2}, {4, 0}}));
  writer.Add(testing::MakeScene(0, 1, {}));  // a late scene fills part of the gap
  writer.Add(testing::MakeScene(4, 12, {}));
  writer.Finish();
  EXPECT_EQ(ReadDataset(dir)["images"].size(), 5u);
  EXPECT_EQ(writer.num_lost(), 2);
}

// Ids follow generator_id * 1e8 + seq + 1 and image id * 1000 + instance_id.
TEST(CocoWriterTest, IdLayout) {
  EXPECT_EQ(CocoWriter::ImageId(0, 0), 1);
  EXPECT_EQ(CocoWriter::ImageId(3, 41), 300000042);
  EXPECT_EQ(CocoWriter::AnnotationId(300000042, 12), 300000042012);
  EXPECT_EQ(CocoWriter::ImageId(kMaxGeneratorId, kMaxSeq), 6553599999999);
  // image ids stay below 2^31 for generator ids 0..20 (README)
  EXPECT_LT(CocoWriter::ImageId(20, kMaxSeq), int64_t{1} << 31);
  EXPECT_GT(CocoWriter::ImageId(21, kMaxSeq), int64_t{1} << 31);
}

// The largest ids (the last generator's last seqs, instances up to 999) are told apart by tools
// that read JSON numbers as doubles, as JavaScript does: Python's json with every integer read
// as a float, and jq. Below 2^53 each id is a double exactly.
TEST(CocoWriterTest, IdsAtTheLimitsSurviveDoubles) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path() + "/out";
  CocoWriter writer(dir);
  for (int64_t seq : {kMaxSeq - 1, kMaxSeq}) {
    ASSERT_TRUE(writer.Add(testing::MakeScene(
        kMaxGeneratorId, seq,
        {testing::MakeInstance(998, 1, "connector", cv::Rect(0, 0, 4, 3), 1.0),
         testing::MakeInstance(999, 1, "connector", cv::Rect(4, 3, 4, 3), 1.0)})));
  }
  writer.Finish();
  const std::vector<int64_t> expected = {6553599999998,    6553599999999,    6553599999998998,
                                         6553599999998999, 6553599999999998, 6553599999999999};
  std::string ids_text;
  for (int64_t id : expected) ids_text += std::to_string(id) + "\n";

  // exact, as nlohmann reads them
  const json dataset = ReadDataset(dir);
  std::vector<int64_t> read;
  for (const char* list : {"images", "annotations"}) {
    for (const json& record : dataset[list]) read.push_back(record["id"].get<int64_t>());
  }
  EXPECT_EQ(read, expected);

  // Python, every integer a float
  std::string out, err;
  ASSERT_EQ(testing::RunToEnd("/usr/bin/python3",
                              {"-c",
                               "import json, sys\n"
                               "d = json.load(open(sys.argv[1]), parse_int=float)\n"
                               "for r in d['images'] + d['annotations']: print(int(r['id']))\n",
                               dir + "/annotations.json"},
                              scratch.path() + "/python", &out, &err, 60),
            0)
      << err;
  EXPECT_EQ(out, ids_text);

  // jq (Debian package jq), whose numbers are doubles
  const std::string jq = testing::FindOnPath("jq");
  if (jq.empty()) GTEST_SKIP() << "jq not on PATH (Debian package jq): its check not run";
  ASSERT_EQ(
      testing::RunToEnd(jq, {"-r", ".images[].id, .annotations[].id", dir + "/annotations.json"},
                        scratch.path() + "/jq", &out, &err, 60),
      0)
      << err;
  EXPECT_EQ(out, ids_text);
}

// A finished dataset resumed and extended equals, byte for byte apart from info, the dataset
// written in one run with the same scenes; counts and categories come back from the journal.
TEST(CocoWriterTest, ResumeAfterFinishEqualsSingleRun) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string single = scratch.path() + "/single";
  const std::string resumed = scratch.path() + "/resumed";
  const std::vector<stackgen::scene> scenes = {SceneA(), SceneB(), testing::SceneD(), SceneC(),
                                               testing::MakeScene(0, 2, {})};
  CocoWriterOptions options;
  options.min_visib_fract = 0.5;
  {
    CocoWriter writer(single, options);
    for (const stackgen::scene& scene : scenes) ASSERT_TRUE(writer.Add(scene));
    writer.Finish();
  }
  {
    CocoWriter writer(resumed, options);
    ASSERT_TRUE(writer.Add(scenes[0]));
    ASSERT_TRUE(writer.Add(scenes[1]));
    ASSERT_TRUE(writer.Add(scenes[2]));
    writer.Finish();
  }
  options.resume = true;
  CocoWriter writer(resumed, options);
  EXPECT_EQ(writer.resumed_scenes(), 3);
  EXPECT_EQ(writer.truncated_journal_bytes(), 0);
  EXPECT_EQ(writer.num_images(), 3);
  // A: 1 and 3 kept, 2 dropped; B: 1 kept; D: 1 kept, 2 crowd, 3 dropped
  EXPECT_EQ(writer.num_annotations(), 4);
  EXPECT_EQ(writer.num_crowd(), 1);
  EXPECT_EQ(writer.num_dropped(), 2);
  EXPECT_FALSE(writer.Add(scenes[1])) << "a stored scene is stored again after resume";
  // a class renamed after resume is still refused: categories came back too
  stackgen::scene renamed = scenes[3];
  renamed.instances[0].class_name = "nut";
  EXPECT_NE(AddError(writer, renamed).find("instances[0].class_name"), std::string::npos);
  ASSERT_TRUE(writer.Add(scenes[3]));
  ASSERT_TRUE(writer.Add(scenes[4]));
  writer.Finish();
  EXPECT_EQ(DatasetBytes(resumed), DatasetBytes(single));
  EXPECT_EQ(writer.num_dropped(), 3);
  EXPECT_EQ(writer.num_lost(), 0);
}

// A journal cut anywhere (inside the last line, just before its '\n', exactly at a line's end,
// inside the first line) resumes with every complete line's scene and its counts, the torn
// bytes cut off, the torn scene's image removed; the scenes sent again complete the dataset.
TEST(CocoWriterTest, ResumeCutsTornLastLine) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::vector<stackgen::scene> scenes = {SceneA(), testing::SceneD(), SceneB(), SceneC()};
  const std::string full = scratch.path() + "/full";
  {
    CocoWriter writer(full);
    for (const stackgen::scene& scene : scenes) ASSERT_TRUE(writer.Add(scene));
    writer.Finish();
  }
  const std::vector<uint64_t> ends = LineEnds(full + "/annotations.journal");
  ASSERT_EQ(ends.size(), scenes.size());
  const std::vector<uint64_t> cuts = {
      0, 10, ends[0], ends[1] + 1, ends[2] - 1, ends[2], ends[2] + 100, ends[3] - 1, ends[3]};
  for (const uint64_t cut : cuts) {
    SCOPED_TRACE("journal cut at byte " + std::to_string(cut));
    // a copy of the dataset whose journal a crash cut at `cut`
    const std::string dir = scratch.path() + "/cut-" + std::to_string(cut);
    fs::copy(full, dir, fs::copy_options::recursive);
    fs::resize_file(dir + "/annotations.journal", cut);
    const size_t complete =
        static_cast<size_t>(std::upper_bound(ends.begin(), ends.end(), cut) - ends.begin());
    const uint64_t kept = complete == 0 ? 0 : ends[complete - 1];

    // the counts a writer that stored just the complete lines' scenes has
    const std::string reference = scratch.path() + "/reference-" + std::to_string(cut);
    CocoWriter expected(reference);
    for (size_t i = 0; i < complete; ++i) expected.Add(scenes[i]);

    CocoWriterOptions options;
    options.resume = true;
    CocoWriter writer(dir, options);
    EXPECT_EQ(writer.resumed_scenes(), static_cast<int64_t>(complete));
    EXPECT_EQ(writer.truncated_journal_bytes(), static_cast<int64_t>(cut - kept));
    EXPECT_EQ(fs::file_size(dir + "/annotations.journal"), kept);
    EXPECT_EQ(writer.num_images(), expected.num_images());
    EXPECT_EQ(writer.num_annotations(), expected.num_annotations());
    EXPECT_EQ(writer.num_crowd(), expected.num_crowd());
    EXPECT_EQ(writer.num_dropped(), expected.num_dropped());
    EXPECT_EQ(writer.StoredSeqs(), expected.StoredSeqs());
    // the images of scenes no complete line records are gone
    size_t images = 0;
    for (const auto& entry : fs::directory_iterator(dir + "/images")) {
      (void)entry;
      ++images;
    }
    EXPECT_EQ(images, complete);

    // every scene sent again: the dataset of the run that was never cut
    for (size_t i = 0; i < scenes.size(); ++i) {
      EXPECT_EQ(writer.Add(scenes[i]), i >= complete) << "scene " << i;
    }
    writer.Finish();
    EXPECT_EQ(DatasetBytes(dir), DatasetBytes(full));
  }
}

// Without resume, a folder holding a journal (a dataset cut short, or finished) is refused,
// naming the file and suggesting --resume; resume needs the journal of an annotations.json;
// a second writer on the same folder is refused; resume of a new folder starts fresh.
TEST(CocoWriterTest, RefusesAJournalWithoutResume) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path() + "/cut-short";
  {
    CocoWriter writer(dir);
    ASSERT_TRUE(writer.Add(SceneA()));
  }
  const std::string journal_error = RuntimeError([&] { CocoWriter again(dir); });
  EXPECT_NE(journal_error.find(dir + "/annotations.journal already exists"), std::string::npos)
      << journal_error;
  EXPECT_NE(journal_error.find("--resume"), std::string::npos) << journal_error;
  EXPECT_EQ(fs::file_size(dir + "/annotations.journal"), LineEnds(dir + "/annotations.journal")[0])
      << "the refused writer changed the journal";
  {
    CocoWriterOptions options;
    options.resume = true;
    CocoWriter writer(dir, options);
    EXPECT_EQ(writer.resumed_scenes(), 1);
    writer.Finish();
    // one writer per folder
    const std::string busy_error = RuntimeError([&] { CocoWriter second(dir, options); });
    EXPECT_NE(busy_error.find(dir + "/annotations.journal is in use"), std::string::npos)
        << busy_error;
  }
  const std::string finished_error = RuntimeError([&] { CocoWriter again(dir); });
  EXPECT_NE(finished_error.find(dir + "/annotations.json already exists"), std::string::npos)
      << finished_error;
  EXPECT_NE(finished_error.find("--resume"), std::string::npos) << finished_error;

  // a dataset without its journal cannot be resumed (nor overwritten)
  fs::remove(dir + "/annotations.journal");
  CocoWriterOptions options;
  options.resume = true;
  const std::string no_journal_error = RuntimeError([&] { CocoWriter writer(dir, options); });
  EXPECT_NE(no_journal_error.find("cannot resume " + dir + "/annotations.json without its journal"),
            std::string::npos)
      << no_journal_error;
  EXPECT_NE(RuntimeError([&] { CocoWriter writer(dir); }).find("annotations.json"),
            std::string::npos);

  // a resumed writer must filter as the journal's did
  const std::string strict = scratch.path() + "/strict";
  {
    CocoWriterOptions strict_options;
    strict_options.min_visib_fract = 0.5;
    CocoWriter writer(strict, strict_options);
    ASSERT_TRUE(writer.Add(SceneA()));
  }
  const std::string filter_error = RuntimeError([&] { CocoWriter writer(strict, options); });
  EXPECT_NE(filter_error.find("line 1 (byte 0): written with min_visib_fract 0.5"),
            std::string::npos)
      << filter_error;

  // nothing there yet: resume starts a new dataset
  CocoWriter fresh(scratch.path() + "/new", options);
  EXPECT_EQ(fresh.resumed_scenes(), 0);
  EXPECT_TRUE(fresh.Add(SceneA()));
}

// A complete journal line that does not parse, in the middle or last, is an error naming the
// journal, the line and its byte offset; the journal is left as it was.
TEST(CocoWriterTest, CorruptJournalLineIsAnError) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  {
    CocoWriter writer(dir);
    for (const stackgen::scene& scene : {SceneA(), SceneB(), SceneC()}) writer.Add(scene);
  }
  const std::string journal = dir + "/annotations.journal";
  const std::string intact = testing::ReadFile(journal);
  const std::vector<uint64_t> ends = LineEnds(journal);
  CocoWriterOptions options;
  options.resume = true;
  for (const size_t line : {size_t{1}, size_t{2}}) {
    SCOPED_TRACE("line " + std::to_string(line + 1));
    // a byte of the line's image record overwritten
    std::string corrupt = intact;
    corrupt[ends[line - 1] + 20] = '#';
    std::ofstream(journal, std::ios::binary | std::ios::trunc) << corrupt;
    const std::string error = RuntimeError([&] { CocoWriter writer(dir, options); });
    EXPECT_NE(error.find(journal + " line " + std::to_string(line + 1) + " (byte " +
                         std::to_string(ends[line - 1]) + "): "),
              std::string::npos)
        << error;
    EXPECT_EQ(testing::ReadFile(journal), corrupt);
  }
  // a record whose lengths do not match its line is caught as well
  std::string shifted = intact;
  const size_t length = shifted.find("\"image_length\":");
  ASSERT_NE(length, std::string::npos);
  shifted[length + 15] = shifted[length + 15] == '9' ? '8' : '9';
  std::ofstream(journal, std::ios::binary | std::ios::trunc) << shifted;
  const std::string error = RuntimeError([&] { CocoWriter writer(dir, options); });
  EXPECT_NE(error.find(journal + " line 1 (byte 0): image_length"), std::string::npos) << error;
}

// Resume removes what an Add or a Finish cut short left behind: temporary files and images that
// no journal line records; an image the journal records but that is gone is an error.
TEST(CocoWriterTest, ResumeRemovesLeftovers) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  {
    CocoWriter writer(dir);
    writer.Add(SceneA());
    writer.Add(SceneB());
  }
  for (const char* name : {"/images/1_000000.png.tmp", "/images/1_000000.png",
                           "/images/7_000003.jpg", "/annotations.json.tmp", "/images/notes.txt"}) {
    std::ofstream(dir + name) << "left over";
  }
  CocoWriterOptions options;
  options.resume = true;
  {
    CocoWriter writer(dir, options);
    EXPECT_EQ(writer.resumed_scenes(), 2);
  }
  ExpectNoTemporaryFiles(dir);
  EXPECT_FALSE(fs::exists(dir + "/images/1_000000.png"));
  EXPECT_FALSE(fs::exists(dir + "/images/7_000003.jpg"));
  EXPECT_TRUE(fs::exists(dir + "/images/0_000000.png"));
  EXPECT_TRUE(fs::exists(dir + "/images/0_000001.png"));
  EXPECT_TRUE(fs::exists(dir + "/images/notes.txt")) << "not a name the writer gives";

  fs::remove(dir + "/images/0_000001.png");
  const std::string error = RuntimeError([&] { CocoWriter writer(dir, options); });
  EXPECT_NE(error.find(dir + "/images/0_000001.png is missing"), std::string::npos) << error;
}

// StoredThrough, Has and StoredSeqs follow gaps and several generators, whatever the order
// scenes arrive in, and come back the same after resume.
TEST(CocoWriterTest, StoredThroughAndHas) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path();
  auto stored = std::make_unique<CocoWriter>(dir);
  CocoWriter& writer = *stored;
  EXPECT_EQ(writer.StoredThrough(0), -1);
  for (const auto& [generator_id, seq] :
       std::vector<std::pair<int, int64_t>>{{0, 1}, {0, 3}, {2, 2}, {2, 1}, {5, 0}, {0, 0}}) {
    ASSERT_TRUE(writer.Add(testing::MakeScene(generator_id, seq, {})));
  }
  EXPECT_EQ(writer.StoredThrough(0), 1);
  EXPECT_EQ(writer.StoredThrough(2), -1) << "seq 0 of generator 2 is missing";
  EXPECT_EQ(writer.StoredThrough(5), 0);
  EXPECT_EQ(writer.StoredThrough(7), -1);
  EXPECT_TRUE(writer.Has(0, 3));
  EXPECT_FALSE(writer.Has(0, 2));
  EXPECT_FALSE(writer.Has(1, 0));
  EXPECT_FALSE(writer.Has(-1, 0));
  EXPECT_FALSE(writer.Has(0, -1));
  EXPECT_FALSE(writer.Has(0, 2000000000)) << "outside the id layout, not generator 2's seq";
  const std::map<int32_t, std::vector<int64_t>> seqs = {{0, {0, 1, 3}}, {2, {1, 2}}, {5, {0}}};
  EXPECT_EQ(writer.StoredSeqs(), seqs);
  // the gap filled: StoredThrough runs on to the end of what is there
  ASSERT_TRUE(writer.Add(testing::MakeScene(0, 2, {})));
  EXPECT_EQ(writer.StoredThrough(0), 3);
  ASSERT_TRUE(writer.Add(testing::MakeScene(2, 0, {})));
  EXPECT_EQ(writer.StoredThrough(2), 2);

  // the same after resume
  const std::map<int32_t, std::vector<int64_t>> all = writer.StoredSeqs();
  stored.reset();
  CocoWriterOptions options;
  options.resume = true;
  const CocoWriter resumed(dir, options);
  EXPECT_EQ(resumed.StoredSeqs(), all);
  EXPECT_EQ(resumed.StoredThrough(0), 3);
  EXPECT_EQ(resumed.StoredThrough(2), 2);
  EXPECT_EQ(resumed.StoredThrough(5), 0);
  EXPECT_TRUE(resumed.Has(2, 1));
}

// kill -9 of a writer mid-run, then a writer resumed on the same folder: every scene the killed
// writer reported stored is there, nothing else is half there, and sending every scene again
// gives each scene exactly once.
TEST(CocoWriterTest, ResumeAfterKill) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string dir = scratch.path() + "/coco";
  // made here: the child only writes (PNG scenes need no encoding)
  std::vector<stackgen::scene> scenes;
  for (int64_t seq = 0; seq < 200; ++seq) {
    scenes.push_back(testing::MakeScene(
        0, seq, {testing::MakeInstance(1, 1, "connector", cv::Rect(1, 2, 3, 3), 1.0)},
        stackgen::image::ENCODING_PNG));
  }
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  const pid_t pid = fork();
  if (pid == 0) {
    // the child stores scenes and says so, one byte per scene, until it is killed
    close(fds[0]);
    CocoWriter writer(dir);
    for (const stackgen::scene& scene : scenes) {
      if (!writer.Add(scene) || write(fds[1], "s", 1) != 1) _exit(1);
    }
    pause();
    _exit(0);
  }
  close(fds[1]);
  int64_t reported = 0;
  char byte;
  while (reported < 20 && read(fds[0], &byte, 1) == 1) ++reported;
  kill(pid, SIGKILL);
  int status = 0;
  waitpid(pid, &status, 0);
  close(fds[0]);
  ASSERT_EQ(reported, 20);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the child failed: " << status;

  CocoWriterOptions options;
  options.resume = true;
  CocoWriter writer(dir, options);
  EXPECT_GE(writer.resumed_scenes(), reported);
  EXPECT_EQ(writer.StoredThrough(0), writer.resumed_scenes() - 1);
  ExpectNoTemporaryFiles(dir);
  for (const stackgen::scene& scene : scenes) {
    EXPECT_EQ(writer.Add(scene), scene.header.seq >= writer.resumed_scenes());
  }
  writer.Finish();
  const json dataset = ReadDataset(dir);
  ASSERT_EQ(dataset["images"].size(), scenes.size());
  for (size_t i = 0; i < scenes.size(); ++i) {
    EXPECT_EQ(dataset["images"][i]["id"], CocoWriter::ImageId(0, static_cast<int64_t>(i)));
  }
  EXPECT_EQ(dataset["annotations"].size(), scenes.size());
}

// A small tmpfs mounted for the test, so the disk really fills (needs root; skipped otherwise).
class CocoWriterFullDiskTest : public ::testing::Test {
 protected:
  void SetUp() override {
    fs::create_directory(disk_);
    if (mount("stackgen-test", disk_.c_str(), "tmpfs", 0, "size=1m") != 0) {
      GTEST_SKIP() << "cannot mount a 1 MiB tmpfs at " << disk_ << " (" << std::strerror(errno)
                   << "; needs root): no full disk to test with";
    }
    mounted_ = true;
  }
  void TearDown() override {
    if (mounted_) umount2(disk_.c_str(), MNT_DETACH);
  }

  // writes `path` until the disk is full
  static void Fill(const std::string& path) {
    std::FILE* file = std::fopen(path.c_str(), "ab");
    ASSERT_NE(file, nullptr);
    const std::vector<char> block(4096, 'x');
    while (std::fwrite(block.data(), 1, block.size(), file) == block.size() &&
           std::fflush(file) == 0) {
    }
    std::fclose(file);
  }

  testing::ScopedTempDir scratch_{"coco-writer"};
  std::string disk_ = scratch_.path() + "/disk";
  bool mounted_ = false;
};

// A full disk: Add throws naming the file and "No space left on device" and leaves nothing of
// the scene; Finish on the full disk fails and keeps the previous annotations.json; with room
// again Finish and Add work, and a resumed writer finds exactly the scenes Add reported stored.
TEST_F(CocoWriterFullDiskTest, DiskFullLeavesValidDataset) {
  const std::string dir = disk_ + "/coco";
  auto writer = std::make_unique<CocoWriter>(dir);
  ASSERT_TRUE(writer->Add(SceneA()));
  ASSERT_TRUE(writer->Add(SceneB()));
  writer->Finish();
  const std::string finished = testing::ReadFile(dir + "/annotations.json");
  // room for half the disk's worth of scenes, then a full disk
  std::ofstream(disk_ + "/room", std::ios::binary) << std::string(400 << 10, 'r');

  // Add until the disk is full
  std::string error;
  int64_t failed_seq = -1;
  for (int64_t seq = 0; seq < 100 && error.empty(); ++seq) {
    const stackgen::scene scene = NoiseScene(3, seq, 64);
    error = RuntimeError([&] { EXPECT_TRUE(writer->Add(scene)); });
    if (!error.empty()) failed_seq = seq;
  }
  ASSERT_GT(failed_seq, 0) << error;
  EXPECT_NE(error.find("cannot write " + dir + "/"), std::string::npos) << error;
  EXPECT_NE(error.find(": No space left on device"), std::string::npos) << error;
  EXPECT_EQ(writer->num_images(), 2 + failed_seq);
  EXPECT_FALSE(writer->Has(3, failed_seq));
  EXPECT_EQ(writer->StoredThrough(3), failed_seq - 1);
  EXPECT_FALSE(
      fs::exists(dir + "/images/3_" + std::string(5, '0') + std::to_string(failed_seq) + ".png"))
      << "the failed scene's image stayed";
  ExpectNoTemporaryFiles(dir);

  // Finish on a full disk keeps the annotations.json there was
  Fill(disk_ + "/filler");
  const std::string finish_error = RuntimeError([&] { writer->Finish(); });
  EXPECT_NE(finish_error.find("cannot write " + dir + "/annotations.json.tmp: No space left"),
            std::string::npos)
      << finish_error;
  EXPECT_EQ(testing::ReadFile(dir + "/annotations.json"), finished);
  ExpectNoTemporaryFiles(dir);

  // room again: Finish writes what was stored, Add goes on
  fs::remove(disk_ + "/filler");
  fs::remove(disk_ + "/room");
  writer->Finish();
  EXPECT_EQ(ReadDataset(dir)["images"].size(), static_cast<size_t>(2 + failed_seq));
  ASSERT_TRUE(writer->Add(NoiseScene(3, failed_seq, 64)));
  writer.reset();

  // the journal holds exactly the stored scenes
  CocoWriterOptions options;
  options.resume = true;
  const CocoWriter resumed(dir, options);
  EXPECT_EQ(resumed.resumed_scenes(), 3 + failed_seq);
  EXPECT_EQ(resumed.truncated_journal_bytes(), 0);
  EXPECT_EQ(resumed.StoredThrough(3), failed_seq);
}

// what a writer in a child process whose files may not grow past a limit did: the scenes Add
// reported stored and the text of the error that stopped it
struct LimitedRun {
  std::vector<int64_t> stored_seqs;
  std::string error;
  int status = -1;
};

// adds `scenes` to a new dataset in `dir` in a forked child whose files may grow to
// `limit_bytes` (SIGXFSZ ignored, so a write past it fails with EFBIG), until an Add throws
// (with `group` > 0: group commits, a Commit after every `group` scenes and at the end, and the
// scenes reported as each commit returns them)
LimitedRun AddWithFileSizeLimit(const std::string& dir, const std::vector<stackgen::scene>& scenes,
                                rlim_t limit_bytes, int group = 0) {
  int fds[2];
  if (pipe(fds) != 0) return {};
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    signal(SIGXFSZ, SIG_IGN);
    const rlimit limit = {limit_bytes, limit_bytes};
    if (setrlimit(RLIMIT_FSIZE, &limit) != 0) _exit(90);
    // "<seq> " per stored scene, then "error: <text>"
    std::string report;
    try {
      CocoWriterOptions options;
      options.group_commit = group > 0;
      CocoWriter writer(dir, options);
      const auto commit = [&] {
        for (const auto& [generator_id, seq] : writer.Commit()) {
          report += std::to_string(seq) + " ";
        }
      };
      for (const stackgen::scene& scene : scenes) {
        if (writer.Add(scene) && group == 0) report += std::to_string(scene.header.seq) + " ";
        if (group > 0 && writer.num_staged() >= group) commit();
      }
      commit();
    } catch (const std::exception& error) {
      report += std::string("error: ") + error.what();
    }
    if (write(fds[1], report.data(), report.size()) != static_cast<ssize_t>(report.size())) {
      _exit(91);
    }
    _exit(0);
  }
  close(fds[1]);
  std::string report;
  char buffer[4096];
  for (ssize_t n; (n = read(fds[0], buffer, sizeof(buffer))) > 0;) report.append(buffer, n);
  close(fds[0]);
  LimitedRun run;
  waitpid(pid, &run.status, 0);
  const size_t error = report.find("error: ");
  std::istringstream seqs(report.substr(0, error));
  for (int64_t seq; seqs >> seq;) run.stored_seqs.push_back(seq);
  if (error != std::string::npos) run.error = report.substr(error + 7);
  return run;
}

// A file that may not grow (EFBIG, from RLIMIT_FSIZE in a child process): when the journal
// cannot grow, Add throws naming it and "File too large", cuts it back and removes the scene's
// image; when an image cannot be written, its .tmp is removed. Either way the journal resumes
// cleanly with exactly the scenes Add reported stored.
TEST(CocoWriterTest, FileSizeLimitLeavesValidJournal) {
  const testing::ScopedTempDir scratch("coco-writer");
  // the scenes are made here: the child only writes (PNG scenes need no encoding)
  std::vector<stackgen::scene> small;
  for (int64_t seq = 0; seq < 40; ++seq) {
    small.push_back(
        testing::MakeScene(0, seq,
                           {testing::MakeInstance(1, 1, "connector", cv::Rect(1, 2, 3, 3), 1.0),
                            testing::MakeInstance(2, 1, "connector", cv::Rect(0, 0, 2, 1), 0.1)},
                           stackgen::image::ENCODING_PNG));
  }
  const std::vector<stackgen::scene> big_image = {small[0], NoiseScene(0, 1, 64), small[2]};
  CocoWriterOptions options;
  options.resume = true;

  // the journal reaches the limit
  const std::string journal_dir = scratch.path() + "/journal";
  const LimitedRun journal_run = AddWithFileSizeLimit(journal_dir, small, 8000);
  ASSERT_TRUE(WIFEXITED(journal_run.status) && WEXITSTATUS(journal_run.status) == 0)
      << journal_run.status;
  EXPECT_EQ(journal_run.error,
            "cannot write " + journal_dir + "/annotations.journal: File too large");
  ASSERT_GT(journal_run.stored_seqs.size(), 1u);
  ASSERT_LT(journal_run.stored_seqs.size(), small.size());
  const int64_t failed_seq = static_cast<int64_t>(journal_run.stored_seqs.size());
  EXPECT_FALSE(fs::exists(journal_dir + "/images/0_00000" + std::to_string(failed_seq) + ".png"))
      << "the image of the scene the journal could not take stayed";
  ExpectNoTemporaryFiles(journal_dir);
  {
    CocoWriter writer(journal_dir, options);
    EXPECT_EQ(writer.truncated_journal_bytes(), 0) << "the journal was not cut back";
    EXPECT_EQ(writer.StoredSeqs(),
              (std::map<int32_t, std::vector<int64_t>>{{0, journal_run.stored_seqs}}));
    EXPECT_EQ(writer.num_dropped(), failed_seq);
    writer.Finish();
    EXPECT_EQ(ReadDataset(journal_dir)["images"].size(), journal_run.stored_seqs.size());
  }

  // an image reaches the limit
  const std::string image_dir = scratch.path() + "/image";
  const LimitedRun image_run = AddWithFileSizeLimit(image_dir, big_image, 8000);
  ASSERT_TRUE(WIFEXITED(image_run.status) && WEXITSTATUS(image_run.status) == 0)
      << image_run.status;
  EXPECT_EQ(image_run.error,
            "cannot write " + image_dir + "/images/0_000001.png.tmp: File too large");
  EXPECT_EQ(image_run.stored_seqs, std::vector<int64_t>{0});
  ExpectNoTemporaryFiles(image_dir);
  {
    CocoWriter writer(image_dir, options);
    EXPECT_EQ(writer.resumed_scenes(), 1);
    EXPECT_EQ(writer.truncated_journal_bytes(), 0);
    EXPECT_TRUE(writer.Has(0, 0));
  }
}

// Group commits: an added scene is only staged (not stored, not Has, not in StoredThrough, but a
// repeat is still refused or reported) until Commit, which returns the scenes in the order added
// and leaves the same journal, byte for byte, as storing each scene on its own; staged scenes
// of a writer that ends without a commit are gone after resume, their image files removed.
TEST(CocoWriterTest, GroupCommitStoresOnlyWhenCommitted) {
  const testing::ScopedTempDir scratch("coco-writer");
  const std::string single_dir = scratch.path() + "/single", group_dir = scratch.path() + "/group";
  CocoWriterOptions grouped;
  grouped.group_commit = true;
  std::vector<stackgen::scene> scenes;
  for (int64_t seq = 0; seq < 7; ++seq) {
    scenes.push_back(testing::MakeScene(
        seq % 2, seq, {testing::MakeInstance(1, 1, "connector", cv::Rect(1, 2, 3, 3), 1.0)},
        stackgen::image::ENCODING_PNG));
  }
  {
    CocoWriter single(single_dir);
    for (int k = 0; k < 5; ++k) ASSERT_TRUE(single.Add(scenes[k]));
  }
  {
    CocoWriter writer(group_dir, grouped);
    for (int k = 0; k < 5; ++k) ASSERT_TRUE(writer.Add(scenes[k]));
    EXPECT_FALSE(writer.Add(scenes[2])) << "a staged scene again";
    stackgen::scene other_run = scenes[2];
    other_run.header.seed += 1;
    EXPECT_THROW(writer.Add(other_run), InvalidSceneError);
    EXPECT_EQ(writer.num_staged(), 5);
    EXPECT_EQ(writer.num_images(), 0);
    EXPECT_FALSE(writer.Has(0, 0));
    EXPECT_EQ(writer.StoredThrough(0), -1);
    const std::vector<std::pair<int32_t, int64_t>> committed = writer.Commit();
    EXPECT_EQ(committed,
              (std::vector<std::pair<int32_t, int64_t>>{{0, 0}, {1, 1}, {0, 2}, {1, 3}, {0, 4}}));
    EXPECT_EQ(writer.num_staged(), 0);
    EXPECT_EQ(writer.num_images(), 5);
    EXPECT_EQ(writer.StoredThrough(0), 0) << "generator 0 has seqs 0, 2 and 4";
    EXPECT_TRUE(writer.Has(1, 3));
    EXPECT_TRUE(writer.Commit().empty());
    EXPECT_EQ(testing::ReadFile(group_dir + "/annotations.journal"),
              testing::ReadFile(single_dir + "/annotations.journal"));
    // two more, never committed: as if the writer were killed now
    ASSERT_TRUE(writer.Add(scenes[5]));
    ASSERT_TRUE(writer.Add(scenes[6]));
    EXPECT_TRUE(fs::exists(group_dir + "/images/1_000005.png"));
  }
  grouped.resume = true;
  CocoWriter resumed(group_dir, grouped);
  EXPECT_EQ(resumed.resumed_scenes(), 5);
  EXPECT_FALSE(fs::exists(group_dir + "/images/1_000005.png"));
  EXPECT_FALSE(fs::exists(group_dir + "/images/0_000006.png"));
  ExpectNoTemporaryFiles(group_dir);
  ASSERT_TRUE(resumed.Add(scenes[5]));
  resumed.Finish();
  EXPECT_EQ(resumed.num_staged(), 0);
  EXPECT_EQ(ReadDataset(group_dir)["images"].size(), 6u) << "Finish commits what is staged";
}

// A group whose journal lines cannot be written (RLIMIT_FSIZE): Commit throws naming the
// journal, the whole group is dropped (its images removed, the journal cut back) and the
// dataset resumes with exactly the scenes earlier commits returned.
TEST(CocoWriterTest, FailedGroupCommitDropsTheGroup) {
  const testing::ScopedTempDir scratch("coco-writer");
  std::vector<stackgen::scene> scenes;
  for (int64_t seq = 0; seq < 40; ++seq) {
    scenes.push_back(testing::MakeScene(
        0, seq, {testing::MakeInstance(1, 1, "connector", cv::Rect(1, 2, 3, 3), 1.0)},
        stackgen::image::ENCODING_PNG));
  }
  const std::string dir = scratch.path() + "/group";
  const LimitedRun run = AddWithFileSizeLimit(dir, scenes, 8000, 4);
  ASSERT_TRUE(WIFEXITED(run.status) && WEXITSTATUS(run.status) == 0) << run.status;
  EXPECT_EQ(run.error, "cannot write " + dir + "/annotations.journal: File too large");
  ASSERT_GE(run.stored_seqs.size(), 4u);
  ASSERT_EQ(run.stored_seqs.size() % 4, 0u) << "only whole groups are stored";
  const size_t failed = run.stored_seqs.size();
  for (size_t seq = failed; seq < failed + 4; ++seq) {
    EXPECT_FALSE(fs::exists(dir + "/images/0_" + std::string(6 - std::to_string(seq).size(), '0') +
                            std::to_string(seq) + ".png"))
        << "the image of scene " << seq << " of the failed group stayed";
  }
  ExpectNoTemporaryFiles(dir);
  CocoWriterOptions options;
  options.resume = true;
  CocoWriter writer(dir, options);
  EXPECT_EQ(writer.truncated_journal_bytes(), 0) << "the journal was not cut back";
  EXPECT_EQ(writer.StoredSeqs(), (std::map<int32_t, std::vector<int64_t>>{{0, run.stored_seqs}}));
}

}  // namespace
}  // namespace stackgen
