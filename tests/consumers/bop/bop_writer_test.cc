// The BOP writer's own rules: floats as the toolkit's Python writes them, models stored once and
// checked, a folder that holds a dataset refused, a 3D camera's depth and point clouds.

#include "consumers/bop/bop_writer.h"
#include "consumers/bop/toolkit_json.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "bus/channels.h"
#include "bus/log.h"
#include "tests/consumers/coco/coco_test_scenes.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using nlohmann::json;
using testing::ReadFile;
namespace fs = std::filesystem;

// a unit cube of 8 vertices and 12 triangles, millimetres, as class `class_id`
model Cube(int32_t class_id, float size) {
  model m{};
  m.class_id = class_id;
  m.class_name = "cube";
  m.mesh = "cube.obj";
  for (int i = 0; i < 8; ++i) {
    m.vertices_mm.push_back({(i & 1) * size, ((i >> 1) & 1) * size, ((i >> 2) & 1) * size});
    m.normals.push_back({0.f, 0.f, 1.f});
  }
  m.num_vertices = 8;
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  m.num_triangles = 12;
  m.diameter_mm = std::sqrt(3.0) * size;
  m.discrete_symmetries = {std::vector<double>(16, 0.0)};
  for (int i = 0; i < 4; ++i) m.discrete_symmetries[0][i * 5] = i == 1 || i == 2 ? -1.0 : 1.0;
  m.discrete_symmetries[0][7] = size;
  m.discrete_symmetries[0][11] = size;
  m.num_discrete_symmetries = 1;
  return m;
}

// doubles come out as Python's repr writes them, so files equal what inout.save_json writes.
TEST(BopWriterTest, FloatsAsPythonWritesThem) {
  EXPECT_EQ(PythonFloat(0.1), "0.1");
  EXPECT_EQ(PythonFloat(1.0), "1.0");
  EXPECT_EQ(PythonFloat(-2.5), "-2.5");
  EXPECT_EQ(PythonFloat(0.0), "0.0");
  EXPECT_EQ(PythonFloat(123456.0), "123456.0");
  EXPECT_EQ(PythonFloat(0.0001), "0.0001");
  EXPECT_EQ(PythonFloat(1e-05), "1e-05");
  EXPECT_EQ(PythonFloat(1.5e-07), "1.5e-07");
  EXPECT_EQ(PythonFloat(1e15), "1000000000000000.0");
  EXPECT_EQ(PythonFloat(1e16), "1e+16");
  EXPECT_EQ(PythonFloat(1.2345678901234568e+17), "1.2345678901234568e+17");
  // nlohmann prints 17 digits here; repr the shortest that reads back the same
  EXPECT_EQ(PythonFloat(0.051587949272662983), "0.05158794927266298");
  EXPECT_EQ(PythonFloat(95.26279441628824), "95.26279441628824");
}

// the first model of a class is stored (PLY and models_info.json in the toolkit's layout); a
// second with another mesh is reported and does not replace it; a broken one is refused.
TEST(BopWriterTest, ModelsAreStoredOnceAndChecked) {
  testing::ScratchDir scratch("stackgen-bop-writer");
  const std::string dir = scratch.path() + "/dataset";
  auto writer = std::make_unique<BopWriter>(dir);
  EXPECT_TRUE(writer->AddModel(Cube(3, 10.f)));
  EXPECT_FALSE(writer->AddModel(Cube(3, 10.f)));
  EXPECT_TRUE(writer->conflicting_models().empty());
  const std::string ply = ReadFile(dir + "/models/obj_000003.ply");
  EXPECT_NE(ply.find("element vertex 8\n"), std::string::npos) << ply;
  EXPECT_NE(ply.find("\n10 10 10 0 0 1\n"), std::string::npos) << ply;
  EXPECT_NE(ply.find("\n3 3 7 5\n"), std::string::npos) << ply;
  EXPECT_EQ(ReadFile(dir + "/models/models_info.json"),
            "{\n  \"3\": {\"diameter\": 17.32050807568877, \"min_x\": 0.0, \"min_y\": 0.0, "
            "\"min_z\": 0.0, \"size_x\": 10.0, \"size_y\": 10.0, \"size_z\": 10.0, "
            "\"symmetries_discrete\": [[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 10.0, 0.0, 0.0, "
            "-1.0, 10.0, 0.0, 0.0, 0.0, 1.0]]}\n}");

  // another mesh for class 3: kept apart, the file unchanged
  EXPECT_FALSE(writer->AddModel(Cube(3, 20.f)));
  EXPECT_EQ(writer->conflicting_models().count(3), 1u);
  EXPECT_EQ(ReadFile(dir + "/models/obj_000003.ply"), ply);

  // a triangle that points past the vertices, a count that lies
  model broken = Cube(4, 10.f);
  broken.triangles[5][1] = 8;
  EXPECT_THROW(writer->AddModel(broken), InvalidSceneError);
  broken = Cube(4, 10.f);
  broken.num_vertices = 9;
  EXPECT_THROW(writer->AddModel(broken), InvalidSceneError);
  EXPECT_FALSE(std::filesystem::exists(dir + "/models/obj_000004.ply"));
  EXPECT_EQ(writer->ModelClasses(), std::set<int32_t>({3}));

  // a resumed writer knows the stored model and compares with its file
  BopWriterOptions resume;
  resume.resume = true;
  writer.reset();
  writer = std::make_unique<BopWriter>(dir, resume);
  EXPECT_EQ(writer->ModelClasses(), std::set<int32_t>({3}));
  EXPECT_FALSE(writer->AddModel(Cube(3, 20.f)));
  EXPECT_EQ(writer->conflicting_models().count(3), 1u);
}

// a folder that holds a dataset (a non-empty journal) is not written over without resume, and a
// second writer cannot open a folder in use.
TEST(BopWriterTest, AnotherDatasetIsRefused) {
  testing::ScratchDir scratch("stackgen-bop-writer");
  const std::string dir = scratch.path() + "/dataset";
  {
    BopWriter writer(dir);
    EXPECT_THROW(BopWriter second(dir), std::runtime_error);
  }
  {
    std::ofstream journal(dir + "/bop.journal");
    journal << "{}\n";
  }
  try {
    BopWriter again(dir);
    FAIL() << "a folder with a journal was opened without resume";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("--resume"), std::string::npos) << error.what();
  }
  // and a journal line that is not ours is named on resume
  BopWriterOptions resume;
  resume.resume = true;
  try {
    BopWriter resumed(dir, resume);
    FAIL() << "a journal of no scene record was resumed";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("bop.journal line 1"), std::string::npos)
        << error.what();
  }
}

// a RAW DEPTH16 image of the test scenes' size, every pixel `value`
image RawDepth(uint16_t value) {
  image out{};
  out.width = testing::kSceneWidth;
  out.height = testing::kSceneHeight;
  out.pixel_format = image::PIXEL_DEPTH16;
  out.encoding = image::ENCODING_RAW;
  for (int k = 0; k < out.width * out.height; ++k) {
    out.data.push_back(static_cast<uint8_t>(value & 0xff));
    out.data.push_back(static_cast<uint8_t>(value >> 8));
  }
  out.size = static_cast<int32_t>(out.data.size());
  return out;
}

// a 3D camera's depth goes to depth/ and the exact one to depth_ideal/; with point_clouds the
// stored depth is also an organised PLY: width x height points, the back-projection of each
// pixel, NaN at a hole; a scene without a 3D camera keeps its exact depth in depth/ alone
TEST(BopWriterTest, SensorDepthBesideTheExactOneAndPointClouds) {
  testing::ScratchDir scratch("stackgen-bop-writer");
  const std::string dir = scratch.path() + "/dataset";
  scene with = testing::SceneA();
  with.depth = RawDepth(5000);  // 500 mm at depth_scale 0.1
  with.depth_sensor = RawDepth(5010);
  const size_t hole = 2 * (1 * testing::kSceneWidth + 2);  // pixel (u 2, v 1)
  with.depth_sensor.data[hole] = with.depth_sensor.data[hole + 1] = 0;
  scene without = testing::SceneB();
  without.depth = RawDepth(6000);
  BopWriterOptions options;
  options.point_clouds = true;
  {
    BopWriter writer(dir, options);
    ASSERT_TRUE(writer.Add(with));
    ASSERT_TRUE(writer.Add(without));
    writer.Finish();
  }
  const std::string chunk = dir + "/train_pbr/000000/";
  const cv::Mat sensor = cv::imread(chunk + "depth/000000.png", cv::IMREAD_UNCHANGED);
  const cv::Mat ideal = cv::imread(chunk + "depth_ideal/000000.png", cv::IMREAD_UNCHANGED);
  ASSERT_EQ(sensor.type(), CV_16UC1);
  ASSERT_EQ(ideal.type(), CV_16UC1);
  EXPECT_EQ(sensor.at<uint16_t>(1, 2), 0);
  EXPECT_EQ(sensor.at<uint16_t>(4, 5), 5010);
  EXPECT_EQ(cv::countNonZero(ideal != 5000), 0);
  EXPECT_EQ(cv::imread(chunk + "depth/000001.png", cv::IMREAD_UNCHANGED).at<uint16_t>(0, 0), 6000);
  EXPECT_FALSE(std::filesystem::exists(chunk + "depth_ideal/000001.png"));

  // the point cloud: its header, then x y z floats row by row
  const std::string ply = ReadFile(chunk + "points/000000.ply");
  const size_t end = ply.find("end_header\n");
  ASSERT_NE(end, std::string::npos);
  const std::string header = ply.substr(0, end);
  EXPECT_EQ(header.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u) << header;
  EXPECT_NE(header.find("obj_info num_cols 8\nobj_info num_rows 6\nelement vertex 48\n"),
            std::string::npos)
      << header;
  const size_t body = end + std::string("end_header\n").size();
  ASSERT_EQ(ply.size(), body + 48 * 3 * sizeof(float));
  const auto point = [&](int u, int v) {
    float xyz[3];
    std::memcpy(xyz, ply.data() + body + 3 * sizeof(float) * (v * 8 + u), sizeof(xyz));
    return std::vector<float>(xyz, xyz + 3);
  };
  EXPECT_TRUE(std::isnan(point(2, 1)[2]));
  const std::vector<float> p = point(5, 4);  // cx 3.5, cy 2.5, fx fy 500, z 501 mm
  EXPECT_FLOAT_EQ(p[0], static_cast<float>((5 - 3.5) * 501.0 / 500));
  EXPECT_FLOAT_EQ(p[1], static_cast<float>((4 - 2.5) * 501.0 / 500));
  EXPECT_FLOAT_EQ(p[2], 501.f);
  EXPECT_TRUE(std::filesystem::exists(chunk + "points/000001.ply"));
}

// the fixture log's scenes (a 3D camera, suction grasps): scene_grasp.json holds, per image, one
// list per ground truth (scene_gt's order, by instance id) with that instance's grasps by rank;
// depth/ is the sensor's and depth_ideal/ the exact depth
TEST(BopWriterTest, GraspsBesideTheGroundTruths) {
  testing::ScratchDir scratch("stackgen-bop-writer");
  const std::string dir = scratch.path() + "/dataset";
  std::vector<scene> scenes;
  ReadLog(std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog",
          [&](const LogEvent& event) {
            if (event.channel == kSceneChannel) scenes.push_back(DecodeLogEvent<scene>(event));
          });
  ASSERT_EQ(scenes.size(), 4u);
  {
    BopWriter writer(dir);
    for (const scene& s : scenes) ASSERT_TRUE(writer.Add(s));
    writer.Finish();
  }
  const std::string chunk = dir + "/train_pbr/2000000/";
  const json grasps = json::parse(ReadFile(chunk + "scene_grasp.json"));
  const json gt = json::parse(ReadFile(chunk + "scene_gt.json"));
  int proven = 0;
  for (const scene& s : scenes) {
    const std::string im = std::to_string(s.header.seq % 1000);
    ASSERT_EQ(grasps.at(im).size(), gt.at(im).size()) << im;
    std::vector<int32_t> ids;
    for (const instance& object : s.instances) ids.push_back(object.instance_id);
    std::sort(ids.begin(), ids.end());
    for (size_t g = 0; g < ids.size(); ++g) {
      std::vector<const suction_grasp*> own;
      for (const suction_grasp& grasp : s.suction_grasps) {
        if (grasp.instance_id == ids[g]) own.push_back(&grasp);
      }
      size_t jaws = 0;
      for (const jaw_grasp& grasp : s.jaw_grasps) jaws += grasp.instance_id == ids[g];
      EXPECT_EQ(grasps[im][g].value("parallel_jaw_grasps", json::array()).size(), jaws);
      const json& stored = grasps[im][g].value("suction_grasps", json::array());
      ASSERT_EQ(stored.size(), own.size()) << im << " gt " << g;
      for (const suction_grasp* grasp : own) {
        const json& record = stored.at(static_cast<size_t>(grasp->rank));
        EXPECT_EQ(record["v"], grasp->v);
        EXPECT_EQ(record["clearance_mm"], grasp->clearance_mm);
        if (grasp->proof != suction_grasp::PROOF_NOT_TRIED) {
          ++proven;
          EXPECT_NE(record["proof"], "not tried");
          EXPECT_EQ(record["num_moved"], grasp->num_moved);
        }
      }
    }
    const std::string file = im.size() < 6 ? std::string(6 - im.size(), '0') + im : im;
    EXPECT_TRUE(fs::exists(chunk + "depth_ideal/" + file + ".png")) << file;
  }
  EXPECT_EQ(proven, 4);
}

}  // namespace
}  // namespace stackgen
