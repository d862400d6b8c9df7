#include "gen/mesh/mesh.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <assimp/config.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <Eigen/Geometry>
#include <assimp/Importer.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

// vertices whose faces meet at more than this angle get one normal per face (a hard edge)
constexpr float kMaxSmoothingAngleDeg = 30.0f;

// a mesh encloses ~zero volume if |volume| is below this fraction of its bounding-box diagonal^3
constexpr double kMinRelativeVolume = 1e-6;

std::string Quoted(const std::string& path) { return "'" + path + "'"; }

// Reads `path` with assimp: triangulated, normals regenerated with hard edges kept flat, texture
// coordinates and materials kept.
const aiScene* ReadScene(Assimp::Importer& importer, const std::string& path, double scale_to_mm) {
  if (!std::isfinite(scale_to_mm) || scale_to_mm <= 0) {
    std::ostringstream message;
    message << "mesh file " << Quoted(path) << ": scale_to_mm must be > 0, got " << scale_to_mm;
    throw std::runtime_error(message.str());
  }
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error)) {
    throw std::runtime_error("mesh file " + Quoted(path) + " does not exist or is not a file");
  }

  // drop everything but positions, faces, texture coordinates and materials; normals are
  // regenerated below
  importer.SetPropertyInteger(AI_CONFIG_PP_RVC_FLAGS,
                              aiComponent_NORMALS | aiComponent_TANGENTS_AND_BITANGENTS |
                                  aiComponent_COLORS | aiComponent_BONEWEIGHTS |
                                  aiComponent_ANIMATIONS | aiComponent_TEXTURES |
                                  aiComponent_LIGHTS | aiComponent_CAMERAS);
  importer.SetPropertyFloat(AI_CONFIG_PP_GSN_MAX_SMOOTHING_ANGLE, kMaxSmoothingAngleDeg);
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE,
                              aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  importer.SetPropertyBool(AI_CONFIG_PP_FD_REMOVE, true);

  const unsigned int flags = aiProcess_RemoveComponent | aiProcess_Triangulate |
                             aiProcess_FindDegenerates | aiProcess_SortByPType |
                             aiProcess_GenSmoothNormals | aiProcess_JoinIdenticalVertices;
  const aiScene* scene = importer.ReadFile(path, flags);
  if (scene == nullptr || scene->mRootNode == nullptr) {
    throw std::runtime_error("cannot read mesh file " + Quoted(path) + ": " +
                             importer.GetErrorString());
  }
  return scene;
}

// Appends one assimp mesh, transformed by `world_from_mesh` and scaled, to `out`; its triangles
// get material `material` (an index into out->materials), or none when it is negative.
void AppendMesh(const aiMesh& mesh, const aiMatrix4x4& world_from_mesh, double scale_to_mm,
                int material, TriangleMesh* out) {
  Eigen::Matrix4d transform;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) transform(r, c) = world_from_mesh[r][c];
  }
  const Eigen::Matrix3d linear = transform.topLeftCorner<3, 3>();
  const Eigen::Matrix3d normal_from_normal = linear.inverse().transpose();
  // a mirroring transform turns counter-clockwise faces clockwise
  const bool mirrored = linear.determinant() < 0;

  // vertices and normals
  const uint32_t first = static_cast<uint32_t>(out->positions_mm.size());
  for (unsigned int i = 0; i < mesh.mNumVertices; ++i) {
    const aiVector3D& p = mesh.mVertices[i];
    const Eigen::Vector3d position =
        scale_to_mm * (linear * Eigen::Vector3d(p.x, p.y, p.z) + transform.topRightCorner<3, 1>());
    out->positions_mm.push_back(position.cast<float>());
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    if (mesh.mNormals != nullptr) {
      const aiVector3D& n = mesh.mNormals[i];
      const Eigen::Vector3d transformed = normal_from_normal * Eigen::Vector3d(n.x, n.y, n.z);
      if (transformed.norm() > 0 && std::isfinite(transformed.norm())) {
        normal = transformed.normalized();
      }
    }
    out->normals.push_back(normal.cast<float>());
  }

  // texture coordinates (channel 0); once any mesh has them, the others get (0, 0)
  const bool has_uvs = mesh.HasTextureCoords(0);
  if (has_uvs || !out->uvs.empty()) {
    out->uvs.resize(first, Eigen::Vector2f::Zero());
    for (unsigned int i = 0; i < mesh.mNumVertices; ++i) {
      out->uvs.push_back(
          has_uvs ? Eigen::Vector2f(mesh.mTextureCoords[0][i].x, mesh.mTextureCoords[0][i].y)
                  : Eigen::Vector2f::Zero());
    }
  }

  // triangles (points and lines were removed by SortByPType)
  for (unsigned int f = 0; f < mesh.mNumFaces; ++f) {
    const aiFace& face = mesh.mFaces[f];
    if (face.mNumIndices != 3) continue;
    std::array<uint32_t, 3> triangle = {first + face.mIndices[0], first + face.mIndices[1],
                                        first + face.mIndices[2]};
    if (mirrored) std::swap(triangle[1], triangle[2]);
    out->triangles.push_back(triangle);
    if (material >= 0) out->triangle_material.push_back(material);
  }
}

// `value` clamped to [lo, hi], or `fallback` when it is not finite.
float ClampOr(float value, float lo, float hi, float fallback) {
  return std::isfinite(value) ? std::clamp(value, lo, hi) : fallback;
}

// Reads the diffuse texture `texture_path` of `model_path` (relative to the model's folder) as
// RGB; `cache` holds the textures already read, by resolved path.
cv::Mat ReadTexture(const std::string& model_path, const std::string& texture_path,
                    std::string* resolved_path, std::map<std::string, cv::Mat>* cache) {
  if (!texture_path.empty() && texture_path[0] == '*') {
    throw std::runtime_error("mesh file " + Quoted(model_path) + ": texture " +
                             Quoted(texture_path) +
                             " is embedded in the model file, which is not supported; save it "
                             "as an image file next to the model");
  }
  // paths written on Windows use backslashes
  std::string relative = texture_path;
  std::replace(relative.begin(), relative.end(), '\\', '/');
  const std::filesystem::path resolved =
      (std::filesystem::path(model_path).parent_path() / relative).lexically_normal();
  *resolved_path = resolved.string();
  const auto cached = cache->find(*resolved_path);
  if (cached != cache->end()) return cached->second;

  std::error_code error;
  if (!std::filesystem::is_regular_file(resolved, error)) {
    throw std::runtime_error("mesh file " + Quoted(model_path) + ": texture " +
                             Quoted(texture_path) + " (" + Quoted(*resolved_path) +
                             ") does not exist or is not a file");
  }
  const cv::Mat bgr = cv::imread(*resolved_path, cv::IMREAD_COLOR);
  if (bgr.empty()) {
    throw std::runtime_error("mesh file " + Quoted(model_path) + ": cannot read texture " +
                             Quoted(*resolved_path) + " as an image");
  }
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  cache->emplace(*resolved_path, rgb);
  return rgb;
}

// The scene material `material` of `model_path` as a MeshMaterial, its texture read.
MeshMaterial ReadMaterial(const std::string& model_path, const aiMaterial& material,
                          std::map<std::string, cv::Mat>* texture_cache) {
  MeshMaterial out;
  aiString name;
  if (material.Get(AI_MATKEY_NAME, name) == aiReturn_SUCCESS) out.name = name.C_Str();

  // colours and highlight
  aiColor3D diffuse;
  if (material.Get(AI_MATKEY_COLOR_DIFFUSE, diffuse) == aiReturn_SUCCESS) {
    out.color = Eigen::Vector3f(ClampOr(diffuse.r, 0, 1, out.color.x()),
                                ClampOr(diffuse.g, 0, 1, out.color.y()),
                                ClampOr(diffuse.b, 0, 1, out.color.z()));
  }
  aiColor3D specular;
  const bool has_specular = material.Get(AI_MATKEY_COLOR_SPECULAR, specular) == aiReturn_SUCCESS;
  if (has_specular) {
    out.specular = ClampOr((specular.r + specular.g + specular.b) / 3, 0, 2, out.specular);
  }
  float shininess = 0;
  if (material.Get(AI_MATKEY_SHININESS, shininess) == aiReturn_SUCCESS) {
    out.shininess = ClampOr(shininess, 1, 1000, out.shininess);
  }
  float factor = 0;
  if (material.Get(AI_MATKEY_METALLIC_FACTOR, factor) == aiReturn_SUCCESS) {
    out.metallic = ClampOr(factor, 0, 1, out.metallic);
  }
  if (material.Get(AI_MATKEY_ROUGHNESS_FACTOR, factor) == aiReturn_SUCCESS) {
    out.roughness = ClampOr(factor, 0, 1, out.roughness);
  }
  // where it is metal: the base colour of a physically based material, the highlight's colour
  // of a classic one
  if (out.metallic >= 0) {
    out.metal_color = out.color;
  } else if (has_specular) {
    out.metal_color = Eigen::Vector3f(ClampOr(specular.r, 0, 1, out.color.x()),
                                      ClampOr(specular.g, 0, 1, out.color.y()),
                                      ClampOr(specular.b, 0, 1, out.color.z()));
  }

  // the diffuse texture (glTF: the base colour texture)
  aiString texture;
  if (material.GetTexture(aiTextureType_DIFFUSE, 0, &texture) == aiReturn_SUCCESS ||
      material.GetTexture(aiTextureType_BASE_COLOR, 0, &texture) == aiReturn_SUCCESS) {
    if (texture.length > 0) {
      out.texture = ReadTexture(model_path, texture.C_Str(), &out.texture_path, texture_cache);
    }
  }
  return out;
}

// Calls `visit(mesh, world_from_mesh)` for every mesh reference in the node tree.
template <typename Visit>
void VisitNodes(const aiScene& scene, const aiNode& node, const aiMatrix4x4& world_from_parent,
                Visit&& visit) {
  const aiMatrix4x4 world_from_node = world_from_parent * node.mTransformation;
  for (unsigned int i = 0; i < node.mNumMeshes; ++i) {
    visit(*scene.mMeshes[node.mMeshes[i]], world_from_node);
  }
  for (unsigned int i = 0; i < node.mNumChildren; ++i) {
    VisitNodes(scene, *node.mChildren[i], world_from_node, visit);
  }
}

// Throws unless `mesh` has triangles, extent in every axis and volume; turns an inside-out mesh
// (negative volume) the right way round. `what` names the file (and piece) in messages.
void CheckAndOrient(const std::string& what, TriangleMesh* mesh) {
  if (mesh->triangles.empty()) {
    throw std::runtime_error("mesh file " + what + " holds no triangles");
  }
  // every coordinate a number (a NaN vertex would read as a flat extent below)
  for (size_t v = 0; v < mesh->positions_mm.size(); ++v) {
    if (!mesh->positions_mm[v].allFinite()) {
      std::ostringstream message;
      message << "mesh file " << what << ": a vertex is not finite (" << mesh->positions_mm[v].x()
              << ", " << mesh->positions_mm[v].y() << ", " << mesh->positions_mm[v].z() << ")";
      throw std::runtime_error(message.str());
    }
  }

  // extent: every axis must be spanned
  const Eigen::Vector3d extent = Bounds(*mesh).sizes();
  const double diagonal = extent.norm();
  if (!(extent.minCoeff() > 1e-6 * std::max(diagonal, 1e-30))) {
    std::ostringstream message;
    message << "mesh file " << what << " is degenerate: extent " << extent.x() << " x "
            << extent.y() << " x " << extent.z() << " mm";
    throw std::runtime_error(message.str());
  }

  // enclosed volume
  const double volume = SignedVolume(*mesh);
  if (!(std::abs(volume) > kMinRelativeVolume * diagonal * diagonal * diagonal)) {
    std::ostringstream message;
    message << "mesh file " << what << " is degenerate: it encloses ~zero volume (" << volume
            << " mm^3 in a " << extent.x() << " x " << extent.y() << " x " << extent.z()
            << " mm box)";
    throw std::runtime_error(message.str());
  }
  if (volume < 0) {
    // flipped in place, so triangle_material stays aligned with triangles
    for (auto& t : mesh->triangles) std::swap(t[1], t[2]);
    for (auto& n : mesh->normals) n = -n;
  }
}

// One closed axis-aligned box, outward-wound, with flat normals (4 vertices per face).
void AppendBox(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, TriangleMesh* mesh) {
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const int a = (axis + 1) % 3;
      const int b = (axis + 2) % 3;
      Eigen::Vector3f normal = Eigen::Vector3f::Zero();
      normal[axis] = side ? 1.0f : -1.0f;
      // corners in (a, b) order; (a, b, axis) is right-handed, so this is ccw seen from +axis
      const uint32_t first = static_cast<uint32_t>(mesh->positions_mm.size());
      const int corners[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
      for (const auto& corner : corners) {
        Eigen::Vector3f p;
        p[axis] = side ? hi[axis] : lo[axis];
        p[a] = corner[0] ? hi[a] : lo[a];
        p[b] = corner[1] ? hi[b] : lo[b];
        mesh->positions_mm.push_back(p);
        mesh->normals.push_back(normal);
      }
      if (side) {
        mesh->triangles.push_back({first, first + 1, first + 2});
        mesh->triangles.push_back({first, first + 2, first + 3});
      } else {
        mesh->triangles.push_back({first, first + 2, first + 1});
        mesh->triangles.push_back({first, first + 3, first + 2});
      }
    }
  }
}

// Throws unless every material library an OBJ file names exists and defines every material it
// uses: assimp quietly invents a gray material otherwise, which would hide the configured colour.
// Other formats are left to assimp.
void CheckObjMaterialFiles(const std::string& path) {
  std::string extension = std::filesystem::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension != ".obj") return;
  std::ifstream obj(path);
  const std::filesystem::path folder = std::filesystem::path(path).parent_path();

  // the libraries and the materials used, with the line that names each
  std::set<std::string> defined;
  std::vector<std::pair<std::string, int>> used;
  std::string line;
  for (int number = 1; std::getline(obj, line); ++number) {
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "usemtl") {
      std::string name;
      std::getline(words >> std::ws, name);
      while (!name.empty() && std::isspace(static_cast<unsigned char>(name.back())))
        name.pop_back();
      used.emplace_back(name, number);
    } else if (keyword == "mtllib") {
      for (std::string library; words >> library;) {
        const std::filesystem::path library_path = folder / library;
        std::ifstream mtl(library_path);
        if (!mtl) {
          throw std::runtime_error("mesh file " + Quoted(path) + ":" + std::to_string(number) +
                                   ": material library " + Quoted(library_path.string()) +
                                   " does not exist or cannot be read");
        }
        for (std::string mtl_line; std::getline(mtl, mtl_line);) {
          std::istringstream mtl_words(mtl_line);
          std::string mtl_keyword, name;
          mtl_words >> mtl_keyword;
          if (mtl_keyword != "newmtl") continue;
          std::getline(mtl_words >> std::ws, name);
          while (!name.empty() && std::isspace(static_cast<unsigned char>(name.back()))) {
            name.pop_back();
          }
          defined.insert(name);
        }
      }
    }
  }
  for (const auto& [name, number] : used) {
    if (defined.count(name) == 0) {
      throw std::runtime_error("mesh file " + Quoted(path) + ":" + std::to_string(number) +
                               ": usemtl " + Quoted(name) +
                               " names a material no mtllib file defines");
    }
  }
}

}  // namespace

int64_t OpenEdges(const TriangleMesh& mesh) {
  // vertices welded by exact position, then every undirected edge counted
  std::map<std::array<float, 3>, int> weld;
  std::vector<int> welded(mesh.positions_mm.size());
  for (size_t v = 0; v < mesh.positions_mm.size(); ++v) {
    const Eigen::Vector3f& p = mesh.positions_mm[v];
    welded[v] =
        weld.emplace(std::array<float, 3>{p.x(), p.y(), p.z()}, static_cast<int>(weld.size()))
            .first->second;
  }
  std::map<std::pair<int, int>, int> edges;
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      const int a = welded[t[k]], b = welded[t[(k + 1) % 3]];
      if (a != b) ++edges[std::minmax(a, b)];
    }
  }
  int64_t open = 0;
  for (const auto& [edge, count] : edges) open += count != 2 ? 1 : 0;
  return open;
}

void CheckClosedSolid(const std::string& what, const TriangleMesh& mesh) {
  const int64_t open = OpenEdges(mesh);
  if (open > 0) {
    throw std::runtime_error("mesh file " + what +
                             " is not a closed solid: " + std::to_string(open) +
                             " edges do not border exactly two triangles (a cut-off or damaged "
                             "file?); a part's mass and collision shape need a closed mesh");
  }
}

double SignedVolume(const TriangleMesh& mesh) {
  double volume = 0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.positions_mm[t[0]].cast<double>();
    const Eigen::Vector3d b = mesh.positions_mm[t[1]].cast<double>();
    const Eigen::Vector3d c = mesh.positions_mm[t[2]].cast<double>();
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh) {
  Eigen::AlignedBox3d bounds;
  for (const Eigen::Vector3f& p : mesh.positions_mm) bounds.extend(p.cast<double>());
  return bounds;
}

TriangleMesh LoadMesh(const std::string& path, double scale_to_mm) {
  Assimp::Importer importer;
  const aiScene* scene = ReadScene(importer, path, scale_to_mm);
  CheckObjMaterialFiles(path);

  // the materials the node tree's meshes use, in the file's order; only assimp's default
  // material (an OBJ without an MTL file) counts as none
  std::vector<bool> used(scene->mNumMaterials, false);
  VisitNodes(*scene, *scene->mRootNode, aiMatrix4x4(), [&](const aiMesh& part, const aiMatrix4x4&) {
    if (part.mMaterialIndex < scene->mNumMaterials) used[part.mMaterialIndex] = true;
  });
  bool only_default = true;
  for (unsigned int m = 0; m < scene->mNumMaterials; ++m) {
    if (!used[m]) continue;
    aiString name;
    scene->mMaterials[m]->Get(AI_MATKEY_NAME, name);
    if (std::string(name.C_Str()) != AI_DEFAULT_MATERIAL_NAME) only_default = false;
  }
  TriangleMesh mesh;
  std::vector<int> material_index(scene->mNumMaterials, -1);  // scene material -> mesh.materials
  std::map<std::string, cv::Mat> texture_cache;
  for (unsigned int m = 0; m < scene->mNumMaterials && !only_default; ++m) {
    if (!used[m]) continue;
    material_index[m] = static_cast<int>(mesh.materials.size());
    mesh.materials.push_back(ReadMaterial(path, *scene->mMaterials[m], &texture_cache));
  }

  // every mesh of the node tree, in the file's frame; a textured material needs coordinates
  VisitNodes(
      *scene, *scene->mRootNode, aiMatrix4x4(),
      [&](const aiMesh& part, const aiMatrix4x4& world_from_mesh) {
        const int material =
            part.mMaterialIndex < scene->mNumMaterials ? material_index[part.mMaterialIndex] : -1;
        if (material >= 0 && !mesh.materials[material].texture.empty() &&
            !part.HasTextureCoords(0)) {
          throw std::runtime_error("mesh file " + Quoted(path) + ": material " +
                                   Quoted(mesh.materials[material].name) + " has texture " +
                                   Quoted(mesh.materials[material].texture_path) + " but mesh " +
                                   Quoted(part.mName.C_Str()) + " has no texture coordinates");
        }
        AppendMesh(part, world_from_mesh, scale_to_mm, material, &mesh);
      });
  CheckAndOrient(Quoted(path), &mesh);
  return mesh;
}

std::vector<TriangleMesh> LoadMeshPieces(const std::string& path, double scale_to_mm) {
  Assimp::Importer importer;
  const aiScene* scene = ReadScene(importer, path, scale_to_mm);

  // one piece per mesh reference of the node tree
  std::vector<TriangleMesh> pieces;
  VisitNodes(*scene, *scene->mRootNode, aiMatrix4x4(),
             [&](const aiMesh& part, const aiMatrix4x4& world_from_mesh) {
               TriangleMesh piece;
               AppendMesh(part, world_from_mesh, scale_to_mm, -1, &piece);
               if (!piece.triangles.empty()) pieces.push_back(std::move(piece));
             });
  if (pieces.empty()) {
    throw std::runtime_error("mesh file " + Quoted(path) + " holds no triangles");
  }
  for (size_t i = 0; i < pieces.size(); ++i) {
    CheckAndOrient(Quoted(path) + " (piece " + std::to_string(i) + ")", &pieces[i]);
  }
  return pieces;
}

TriangleMesh MakeSquareMesh(float size_mm) {
  TriangleMesh mesh;
  const float h = size_mm / 2;
  mesh.positions_mm = {{-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, h, 0}};
  mesh.normals.assign(4, Eigen::Vector3f::UnitZ());
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return mesh;
}

TriangleMesh MakeOpenBinMesh(double inner_length_mm, double inner_width_mm, double inner_height_mm,
                             double wall_mm) {
  if (!(inner_length_mm > 0 && inner_width_mm > 0 && inner_height_mm > 0 && wall_mm > 0)) {
    std::ostringstream message;
    message << "MakeOpenBinMesh: every size must be > 0, got inner " << inner_length_mm << " x "
            << inner_width_mm << " x " << inner_height_mm << " mm, wall " << wall_mm << " mm";
    throw std::runtime_error(message.str());
  }
  const float l = static_cast<float>(inner_length_mm / 2);
  const float w = static_cast<float>(inner_width_mm / 2);
  const float h = static_cast<float>(inner_height_mm);
  const float t = static_cast<float>(wall_mm);

  // floor below the inner floor (z = 0), then walls: the x walls span the full outer width
  TriangleMesh bin;
  AppendBox({-l - t, -w - t, -t}, {l + t, w + t, 0}, &bin);
  AppendBox({-l - t, -w - t, 0}, {-l, w + t, h}, &bin);
  AppendBox({l, -w - t, 0}, {l + t, w + t, h}, &bin);
  AppendBox({-l, -w - t, 0}, {l, -w, h}, &bin);
  AppendBox({-l, w, 0}, {l, w + t, h}, &bin);
  return bin;
}

}  // namespace stackgen
