// The BOP writer's own rules: floats as the toolkit's Python writes them, models stored once and
// checked, a folder that holds a dataset refused.

#include "consumers/bop/bop_writer.h"
#include "consumers/bop/toolkit_json.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tests/support/process.h"

namespace stackgen {
namespace {

using nlohmann::json;
using testing::ReadFile;

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

}  // namespace
}  // namespace stackgen
