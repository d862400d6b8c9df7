#include "gen/mesh/mesh.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

namespace stackgen {
namespace {

namespace fs = std::filesystem;

// a 2 x 2 x 2 cube centred at (1, 0, 0), faces as quads
constexpr char kCubeObj[] = R"(# unit test cube
v 0 -1 -1
v 2 -1 -1
v 2 1 -1
v 0 1 -1
v 0 -1 1
v 2 -1 1
v 2 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
)";

// a tetrahedron with corners at the origin and on the three axes (4 triangles)
constexpr char kTetraStl[] = R"(solid tetra
facet normal 0 0 -1
  outer loop
    vertex 0 0 0
    vertex 0 3 0
    vertex 3 0 0
  endloop
endfacet
facet normal 0 -1 0
  outer loop
    vertex 0 0 0
    vertex 3 0 0
    vertex 0 0 3
  endloop
endfacet
facet normal -1 0 0
  outer loop
    vertex 0 0 0
    vertex 0 0 3
    vertex 0 3 0
  endloop
endfacet
facet normal 1 1 1
  outer loop
    vertex 3 0 0
    vertex 0 3 0
    vertex 0 0 3
  endloop
endfacet
endsolid tetra
)";

// two unit cubes side by side as separate objects
constexpr char kTwoCubesObj[] = R"(o left
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
o right
v 3 0 0
v 4 0 0
v 4 1 0
v 3 1 0
v 3 0 1
v 4 0 1
v 4 1 1
v 3 1 1
f 9 12 11 10
f 13 14 15 16
f 9 10 14 13
f 10 11 15 14
f 11 12 16 15
f 12 9 13 16
)";

// a flat square: triangles but no extent in z
constexpr char kFlatObj[] = R"(v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
f 1 2 3 4
)";

class MeshTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("stackgen_mesh_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& text) {
    const fs::path path = dir_ / name;
    std::ofstream(path) << text;
    return path.string();
  }

  fs::path dir_;
};

struct FloatBounds {
  Eigen::Vector3f lo;
  Eigen::Vector3f hi;
};

FloatBounds BoundsOf(const TriangleMesh& mesh) {
  const Eigen::AlignedBox3d bounds = Bounds(mesh);
  return {bounds.min().cast<float>(), bounds.max().cast<float>()};
}

// the message of the error LoadMesh throws for `path`, or "" when it loads.
std::string LoadError(const std::string& path) {
  try {
    LoadMesh(path, 1.0);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

// Every edge, with vertices welded by position, is used once in each direction.
bool IsClosedAndConsistent(const TriangleMesh& mesh) {
  std::map<std::tuple<float, float, float>, int> ids;
  auto id = [&](uint32_t v) {
    const auto& p = mesh.positions_mm[v];
    return ids.emplace(std::make_tuple(p.x(), p.y(), p.z()), static_cast<int>(ids.size()))
        .first->second;
  };
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) ++directed[{id(t[k]), id(t[(k + 1) % 3])}];
  }
  for (const auto& [edge, count] : directed) {
    const auto reverse = directed.find({edge.second, edge.first});
    if (count != 1 || reverse == directed.end() || reverse->second != 1) return false;
  }
  return true;
}

// An OBJ with quads loads as triangles with its bounds, outward winding and flat normals.
TEST_F(MeshTest, LoadsObjCube) {
  const TriangleMesh mesh = LoadMesh(Write("cube.obj", kCubeObj), 1.0);
  EXPECT_EQ(mesh.triangles.size(), 12u);
  ASSERT_EQ(mesh.normals.size(), mesh.positions_mm.size());
  // hard 90 degree edges: each corner is split into one vertex per face
  EXPECT_EQ(mesh.positions_mm.size(), 24u);
  const FloatBounds b = BoundsOf(mesh);
  EXPECT_TRUE(b.lo.isApprox(Eigen::Vector3f(0, -1, -1)));
  EXPECT_TRUE(b.hi.isApprox(Eigen::Vector3f(2, 1, 1)));
  EXPECT_NEAR(SignedVolume(mesh), 8.0, 1e-5);
  EXPECT_TRUE(IsClosedAndConsistent(mesh));
  // every normal is a face normal: one axis component is +-1
  for (const auto& n : mesh.normals) EXPECT_NEAR(n.cwiseAbs().maxCoeff(), 1.0f, 1e-5f);
}

// scale_to_mm multiplies every coordinate.
TEST_F(MeshTest, ScalesToMillimetres) {
  const TriangleMesh mesh = LoadMesh(Write("cube.obj", kCubeObj), 10.0);
  const FloatBounds b = BoundsOf(mesh);
  EXPECT_TRUE(b.lo.isApprox(Eigen::Vector3f(0, -10, -10)));
  EXPECT_TRUE(b.hi.isApprox(Eigen::Vector3f(20, 10, 10)));
  EXPECT_NEAR(SignedVolume(mesh), 8000.0, 1e-2);
}

// An ASCII STL loads with its triangle count, bounds and volume.
TEST_F(MeshTest, LoadsAsciiStl) {
  const TriangleMesh mesh = LoadMesh(Write("tetra.stl", kTetraStl), 10.0);
  EXPECT_EQ(mesh.triangles.size(), 4u);
  const FloatBounds b = BoundsOf(mesh);
  EXPECT_TRUE(b.lo.isApprox(Eigen::Vector3f(0, 0, 0)));
  EXPECT_TRUE(b.hi.isApprox(Eigen::Vector3f(30, 30, 30)));
  EXPECT_NEAR(SignedVolume(mesh), 30.0 * 30 * 30 / 6, 1e-2);
  EXPECT_TRUE(IsClosedAndConsistent(mesh));
}

// A missing file is an error that names the path.
TEST_F(MeshTest, MissingFileNamesPath) {
  const std::string path = (dir_ / "no_such_part.obj").string();
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
}

// An empty file is an error that names the path.
TEST_F(MeshTest, EmptyFileIsError) {
  const std::string path = Write("empty.obj", "");
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
}

// A flat mesh (no extent in one axis) is refused as degenerate.
TEST_F(MeshTest, FlatMeshIsDegenerate) {
  const std::string path = Write("flat.obj", kFlatObj);
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("degenerate"), std::string::npos) << error;
}

// A vertex that is not a number is refused as such (it read as a flat extent before).
TEST_F(MeshTest, NonFiniteVertexIsError) {
  std::string obj = kCubeObj;
  obj.replace(obj.find("v 2 1 1"), 7, "v 2 1 nan");
  const std::string path = Write("nan.obj", obj);
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("a vertex is not finite"), std::string::npos) << error;
}

// A closed solid has no open edges; a cube missing a face, as a cut-off file is, has four (the
// rim of the hole), and CheckClosedSolid names the file.
TEST_F(MeshTest, OpenMeshIsNotASolid) {
  const TriangleMesh cube = LoadMesh(Write("cube.obj", kCubeObj), 1.0);
  EXPECT_EQ(OpenEdges(cube), 0);
  EXPECT_NO_THROW(CheckClosedSolid("cube.obj", cube));
  std::string obj = kCubeObj;
  obj.erase(obj.find("f 4 1 5 8"));
  const TriangleMesh cut = LoadMesh(Write("cut.obj", obj), 1.0);
  EXPECT_EQ(OpenEdges(cut), 4);
  try {
    CheckClosedSolid("'cut.obj'", cut);
    ADD_FAILURE() << "an open mesh passed";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("mesh file 'cut.obj' is not a closed solid: 4 edges"),
              std::string::npos)
        << error.what();
  }
  EXPECT_EQ(OpenEdges(LoadMesh(
                std::string(STACKGEN_SOURCE_DIR) + "/config/models/corner_connector.obj", 1.0)),
            0);
}

// A non-positive scale is refused.
TEST_F(MeshTest, BadScaleIsError) {
  EXPECT_THROW(LoadMesh(Write("cube.obj", kCubeObj), 0.0), std::runtime_error);
}

// Each object of an OBJ is one piece; LoadMesh joins them.
TEST_F(MeshTest, LoadsPieces) {
  const std::string path = Write("two.obj", kTwoCubesObj);
  const std::vector<TriangleMesh> pieces = LoadMeshPieces(path, 1.0);
  ASSERT_EQ(pieces.size(), 2u);
  const FloatBounds left = BoundsOf(pieces[0]);
  const FloatBounds right = BoundsOf(pieces[1]);
  EXPECT_TRUE(left.lo.isApprox(Eigen::Vector3f(0, 0, 0)));
  EXPECT_TRUE(right.hi.isApprox(Eigen::Vector3f(4, 1, 1)));
  for (const auto& piece : pieces) {
    EXPECT_EQ(piece.triangles.size(), 12u);
    EXPECT_NEAR(SignedVolume(piece), 1.0, 1e-5);
  }
  const TriangleMesh joined = LoadMesh(path, 1.0);
  EXPECT_EQ(joined.triangles.size(), 24u);
  EXPECT_NEAR(SignedVolume(joined), 2.0, 1e-5);
}

// An inside-out mesh is turned outward-facing.
TEST_F(MeshTest, InsideOutMeshIsReoriented) {
  std::string inverted = kCubeObj;
  // reverse every face's vertex order
  inverted = R"(v 0 -1 -1
v 2 -1 -1
v 2 1 -1
v 0 1 -1
v 0 -1 1
v 2 -1 1
v 2 1 1
v 0 1 1
f 2 3 4 1
f 8 7 6 5
f 5 6 2 1
f 6 7 3 2
f 7 8 4 3
f 8 5 1 4
)";
  const TriangleMesh mesh = LoadMesh(Write("inverted.obj", inverted), 1.0);
  EXPECT_NEAR(SignedVolume(mesh), 8.0, 1e-5);
  // normals still point away from the centre
  for (size_t i = 0; i < mesh.positions_mm.size(); ++i) {
    EXPECT_GT(mesh.normals[i].dot(mesh.positions_mm[i] - Eigen::Vector3f(1, 0, 0)), 0);
  }
}

// the textured box fixture: a cube whose top face shows quadrants.png (material "label")
std::string TexturedBoxPath() {
  return std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/models/textured_box/textured_box.obj";
}

// The index of the material named `name`, or -1.
int MaterialIndex(const TriangleMesh& mesh, const std::string& name) {
  for (size_t m = 0; m < mesh.materials.size(); ++m) {
    if (mesh.materials[m].name == name) return static_cast<int>(m);
  }
  return -1;
}

// An OBJ with an MTL file: Kd, Ks (mean) and Ns are read, the map_Kd PNG is loaded as RGB with
// its size, every triangle has its material and every vertex its texture coordinate.
TEST_F(MeshTest, ReadsMaterialsAndTexture) {
  const TriangleMesh mesh = LoadMesh(TexturedBoxPath(), 50.0);
  ASSERT_EQ(mesh.materials.size(), 2u);
  const int body = MaterialIndex(mesh, "body");
  const int label = MaterialIndex(mesh, "label");
  ASSERT_GE(body, 0);
  ASSERT_GE(label, 0);
  const MeshMaterial& b = mesh.materials[body];
  EXPECT_TRUE(b.color.isApprox(Eigen::Vector3f(0.2f, 0.4f, 0.8f))) << b.color.transpose();
  EXPECT_NEAR(b.specular, 0.1f, 1e-6f);
  EXPECT_NEAR(b.shininess, 10.f, 1e-6f);
  EXPECT_TRUE(b.texture.empty());
  EXPECT_TRUE(b.texture_path.empty());
  const MeshMaterial& l = mesh.materials[label];
  EXPECT_TRUE(l.color.isApprox(Eigen::Vector3f(1, 1, 1)));
  EXPECT_NEAR(l.specular, 0.4f, 1e-6f);
  EXPECT_NEAR(l.shininess, 64.f, 1e-6f);
  // a classic material: where it is metal, its colour is its highlight's (Ks)
  EXPECT_TRUE(b.metal_color.isApprox(Eigen::Vector3f(0.1f, 0.1f, 0.1f))) << b.metal_color;
  EXPECT_TRUE(l.metal_color.isApprox(Eigen::Vector3f(0.3f, 0.4f, 0.5f))) << l.metal_color;

  // the texture: 64 x 64 RGB, red at the top left, green top right, blue bottom left
  EXPECT_EQ(fs::path(l.texture_path).filename(), "quadrants.png");
  EXPECT_TRUE(fs::exists(l.texture_path)) << l.texture_path;
  ASSERT_EQ(l.texture.type(), CV_8UC3);
  EXPECT_EQ(l.texture.size(), cv::Size(64, 64));
  EXPECT_EQ(l.texture.at<cv::Vec3b>(0, 0), cv::Vec3b(255, 0, 0));
  EXPECT_EQ(l.texture.at<cv::Vec3b>(0, 63), cv::Vec3b(0, 255, 0));
  EXPECT_EQ(l.texture.at<cv::Vec3b>(63, 0), cv::Vec3b(0, 0, 255));
  EXPECT_EQ(l.texture.at<cv::Vec3b>(63, 63), cv::Vec3b(255, 255, 255));

  // per-triangle materials: the top face (2 triangles) is the label, the rest the body
  ASSERT_EQ(mesh.triangle_material.size(), mesh.triangles.size());
  ASSERT_EQ(mesh.uvs.size(), mesh.positions_mm.size());
  int label_triangles = 0;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (mesh.triangle_material[t] != label) {
      EXPECT_EQ(mesh.triangle_material[t], body);
      continue;
    }
    ++label_triangles;
    // label vertices lie on the top face, with u along +x and v along +y
    for (const uint32_t v : mesh.triangles[t]) {
      const Eigen::Vector3f& p = mesh.positions_mm[v];
      EXPECT_NEAR(p.z(), 50.f, 1e-4f);
      EXPECT_NEAR(mesh.uvs[v].x(), (p.x() / 50 + 1) / 2, 1e-6f) << "vertex " << v;
      EXPECT_NEAR(mesh.uvs[v].y(), (p.y() / 50 + 1) / 2, 1e-6f) << "vertex " << v;
    }
  }
  EXPECT_EQ(label_triangles, 2);
  EXPECT_NEAR(SignedVolume(mesh), 100.0 * 100 * 100, 1e-2);
}

// An OBJ without an MTL file (assimp's default material only) and an STL have no materials and
// no texture coordinates, so the caller's colour applies.
TEST_F(MeshTest, NoMaterialsWithoutMtl) {
  for (const std::string& path : {Write("cube.obj", kCubeObj), Write("tetra.stl", kTetraStl)}) {
    const TriangleMesh mesh = LoadMesh(path, 1.0);
    EXPECT_TRUE(mesh.materials.empty()) << path << ": " << mesh.materials.size() << " materials, "
                                        << "first " << mesh.materials.front().name;
    EXPECT_TRUE(mesh.triangle_material.empty()) << path;
    EXPECT_TRUE(mesh.uvs.empty()) << path;
  }
}

// A missing texture file is an error naming the model file and the texture.
TEST_F(MeshTest, MissingTextureNamesIt) {
  Write("box.mtl", "newmtl skin\nKd 1 1 1\nmap_Kd no_such_texture.png\n");
  const std::string path =
      Write("box.obj", std::string("mtllib box.mtl\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n") +
                           "usemtl skin\n" + kCubeObj);
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("no_such_texture.png"), std::string::npos) << error;
}

// A missing MTL file, or a usemtl name no MTL file defines, is an error naming the OBJ line (assimp
// would quietly use a gray material instead of the configured colour).
TEST_F(MeshTest, MissingMaterialLibraryOrMaterialNamesTheLine) {
  const std::string missing =
      Write("box.obj", std::string("mtllib missing.mtl\nusemtl shiny\n") + kCubeObj);
  std::string error = LoadError(missing);
  EXPECT_NE(error.find(missing + "':1: material library"), std::string::npos) << error;
  EXPECT_NE(error.find("missing.mtl"), std::string::npos) << error;
  Write("box.mtl", "newmtl matte\nKd 1 0 0\n");
  const std::string undefined =
      Write("box2.obj", std::string("mtllib box.mtl\nusemtl shiny\n") + kCubeObj);
  error = LoadError(undefined);
  EXPECT_NE(error.find(undefined + "':2: usemtl 'shiny'"), std::string::npos) << error;
}

// A textured material on faces without texture coordinates is an error naming the texture.
TEST_F(MeshTest, TextureWithoutCoordinatesIsError) {
  fs::copy_file(fs::path(TexturedBoxPath()).parent_path() / "quadrants.png", dir_ / "q.png");
  Write("box.mtl", "newmtl skin\nKd 1 1 1\nmap_Kd q.png\n");
  const std::string path =
      Write("box.obj", std::string("mtllib box.mtl\nusemtl skin\n") + kCubeObj);
  const std::string error = LoadError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("q.png"), std::string::npos) << error;
  EXPECT_NE(error.find("texture coordinates"), std::string::npos) << error;
}

// An MTL material with physically based factors (Pm, Pr): its Kd is the base colour, metal
// where it is metal; Ks is only the dielectric's highlight.
TEST_F(MeshTest, PhysicallyBasedMtlFactors) {
  std::ofstream(dir_ / "pbr.mtl")
      << "newmtl brass\nKd 0.9 0.6 0.2\nKs 0.1 0.1 0.1\nPm 0.8\nPr 0.3\n";
  const TriangleMesh mesh = LoadMesh(Write("pbr.obj", R"(mtllib pbr.mtl
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
usemtl brass
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
)"),
                                     1.0);
  ASSERT_EQ(mesh.materials.size(), 1u);
  const MeshMaterial& brass = mesh.materials[0];
  EXPECT_NEAR(brass.metallic, 0.8f, 1e-6f);
  EXPECT_NEAR(brass.roughness, 0.3f, 1e-6f);
  EXPECT_TRUE(brass.metal_color.isApprox(Eigen::Vector3f(0.9f, 0.6f, 0.2f))) << brass.metal_color;
}

// An inside-out textured mesh is turned outward with each triangle keeping its material.
TEST_F(MeshTest, ReorientingKeepsTriangleMaterials) {
  const fs::path fixture = fs::path(TexturedBoxPath()).parent_path();
  fs::copy_file(fixture / "quadrants.png", dir_ / "quadrants.png");
  fs::copy_file(fixture / "textured_box.mtl", dir_ / "textured_box.mtl");
  // the fixture with every face's vertex order reversed
  const std::string inverted = R"(mtllib textured_box.mtl
v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl body
f 2 3 4 1
f 5 6 2 1
f 6 7 3 2
f 7 8 4 3
f 8 5 1 4
usemtl label
f 8/4 7/3 6/2 5/1
)";
  const TriangleMesh mesh = LoadMesh(Write("textured_box.obj", inverted), 1.0);
  EXPECT_NEAR(SignedVolume(mesh), 8.0, 1e-5);
  const int label = MaterialIndex(mesh, "label");
  ASSERT_GE(label, 0);
  ASSERT_EQ(mesh.triangle_material.size(), mesh.triangles.size());
  int label_triangles = 0;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Eigen::Vector3f normal =
        (mesh.positions_mm[tri[1]] - mesh.positions_mm[tri[0]])
            .cross(mesh.positions_mm[tri[2]] - mesh.positions_mm[tri[0]]);
    // the label is the top face, now wound to face +z
    if (mesh.triangle_material[t] == label) {
      ++label_triangles;
      EXPECT_GT(normal.z(), 0) << "triangle " << t;
    } else {
      EXPECT_LE(normal.z(), 1e-6f) << "triangle " << t;
    }
  }
  EXPECT_EQ(label_triangles, 2);
}

// The built-in connector is closed, outward-wound and in its documented frame.
TEST_F(MeshTest, BuiltInConnector) {
  const std::string dir = std::string(STACKGEN_SOURCE_DIR) + "/config/models/";
  const TriangleMesh mesh = LoadMesh(dir + "corner_connector.obj", 1.0);
  EXPECT_TRUE(IsClosedAndConsistent(mesh));
  const FloatBounds b = BoundsOf(mesh);
  EXPECT_TRUE(b.lo.isApprox(Eigen::Vector3f(-27.5f, -27.5f, 0), 1e-5f)) << b.lo.transpose();
  EXPECT_TRUE(b.hi.isApprox(Eigen::Vector3f(27.5f, 27.5f, 55), 1e-5f)) << b.hi.transpose();
  // two plates, a gusset, two 8.5 mm holes
  EXPECT_NEAR(SignedVolume(mesh), 35518.4, 1.0);
  const std::vector<TriangleMesh> pieces =
      LoadMeshPieces(dir + "corner_connector_collision.obj", 1.0);
  EXPECT_GT(pieces.size(), 2u);
  double pieces_volume = 0;
  for (const auto& piece : pieces) pieces_volume += SignedVolume(piece);
  // the square-approximated holes remove a little more than the round ones
  EXPECT_NEAR(pieces_volume, SignedVolume(mesh), 0.01 * SignedVolume(mesh));
}

// The open bin spans the inner box plus walls, with the inner floor at z = 0.
TEST_F(MeshTest, OpenBinBounds) {
  const TriangleMesh bin = MakeOpenBinMesh(200, 150, 100, 5);
  const FloatBounds b = BoundsOf(bin);
  EXPECT_TRUE(b.lo.isApprox(Eigen::Vector3f(-105, -80, -5)));
  EXPECT_TRUE(b.hi.isApprox(Eigen::Vector3f(105, 80, 100)));
  EXPECT_EQ(bin.normals.size(), bin.positions_mm.size());
  // floor and walls: 5 closed boxes
  EXPECT_EQ(bin.triangles.size(), 5u * 12u);
  // the x walls span the outer width, the y walls the inner length
  const double walls = 2 * (5.0 * 160 * 100) + 2 * (200.0 * 5 * 100);
  EXPECT_NEAR(SignedVolume(bin), 210.0 * 160 * 5 + walls, 1.0);
  EXPECT_THROW(MakeOpenBinMesh(0, 150, 100, 5), std::runtime_error);
}

}  // namespace
}  // namespace stackgen
