#include "consumers/coco/coco_writer.h"

#include <array>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

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
  EXPECT_TRUE(dataset["info"]["date_created"].is_string());
  EXPECT_EQ(dataset["licenses"], json::array());

  // images: ids generator_id * 1e9 + seq + 1, sorted, with their files
  const json& images = dataset["images"];
  ASSERT_EQ(images.size(), 3u);
  EXPECT_EQ(images[0]["id"], 1);
  EXPECT_EQ(images[1]["id"], 2);
  EXPECT_EQ(images[2]["id"], 1000000001);
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
  EXPECT_EQ(ids, (std::vector<int64_t>{1001, 1003, 2001, 1000000001007}));
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

  // nothing temporary is left once the writer is gone
  writer.reset();
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
    EXPECT_EQ(name.find("journal"), std::string::npos) << name;
  }
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
  scene.instances[0].bbox_obj[2] = scene.camera.width + 1;
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
  EXPECT_EQ(annotated["id"], 2000000001001);
  EXPECT_EQ(annotated["iscrowd"], 0);
  EXPECT_EQ(annotated["px_count_all"], 10);
  const json& crowd = annotations[1];
  EXPECT_EQ(crowd["id"], 2000000001002);
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
              (std::vector<int64_t>{1001, 1003, 2000000001001, 2000000001002}));
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

// Two writers fed the same scenes in different orders write identical images and annotations.
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
  const json a = ReadDataset(dir_a);
  const json b = ReadDataset(dir_b);
  EXPECT_EQ(a["annotations"], b["annotations"]);
  EXPECT_EQ(a["images"], b["images"]);
  EXPECT_EQ(a["categories"], b["categories"]);
  EXPECT_EQ(a["annotations"].dump(), b["annotations"].dump());
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

// Ids follow generator_id * 1e9 + seq + 1 and image id * 1000 + instance_id.
TEST(CocoWriterTest, IdLayout) {
  EXPECT_EQ(CocoWriter::ImageId(0, 0), 1);
  EXPECT_EQ(CocoWriter::ImageId(3, 41), 3000000042);
  EXPECT_EQ(CocoWriter::AnnotationId(3000000042, 12), 3000000042012);
}

}  // namespace
}  // namespace stackgen
