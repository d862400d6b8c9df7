#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

namespace stackgen {

/// A surface material read from the model file (assimp), display colours in [0, 1].
struct MeshMaterial {
  std::string name;
  Eigen::Vector3f color{0.7f, 0.7f, 0.7f};  // diffuse colour (OBJ/MTL Kd; glTF base colour)
  float specular = 0.5f;   // highlight strength: mean of Ks (OBJ), clamped to [0, 2]
  float shininess = 32.f;  // Blinn-Phong exponent (MTL Ns), clamped to [1, 1000]
  /// Physically based factors where the file states them (glTF metallicFactor and
  /// roughnessFactor, MTL Pm and Pr), each in [0, 1]; -1 where it does not.
  float metallic = -1.f;
  float roughness = -1.f;
  /// Physically based: the colour where the surface is metal (its reflectance at normal
  /// incidence, display values). A file that states PBR factors gives its base colour (`color`);
  /// a classic one (OBJ/MTL without Pm) its specular colour Ks, as a metal's colour is its
  /// highlight's (the connector's Ks 0.85 against Kd 0.62); -1 where it states neither.
  Eigen::Vector3f metal_color{-1.f, -1.f, -1.f};
  std::string texture_path;  // the diffuse texture file (map_Kd), resolved; empty = none
  cv::Mat texture;  // CV_8UC3 RGB (not BGR), row 0 = top row of the image file; empty = none
};

/// A triangle mesh in millimetres, in its own (object) frame. Vertices at hard edges (and at
/// texture seams) are duplicated so every vertex has one normal and one texture coordinate
/// (flat-shaded CAD parts look right).
struct TriangleMesh {
  std::vector<Eigen::Vector3f> positions_mm;
  /// Unit normal per vertex, same size as positions_mm.
  std::vector<Eigen::Vector3f> normals;
  /// Indices into positions_mm, counter-clockwise seen from outside.
  std::vector<std::array<uint32_t, 3>> triangles;
  /// Texture coordinates per vertex (u right, v up: v = 0 is the bottom row of the texture image,
  /// as in OBJ), same size as positions_mm, or empty when the file has none.
  std::vector<Eigen::Vector2f> uvs;
  /// Materials of the file; empty when it has none worth using (only assimp's default material,
  /// which every OBJ without an MTL file gets, so the caller's colour applies).
  std::vector<MeshMaterial> materials;
  /// Per triangle, an index into materials; empty when materials is empty.
  std::vector<int> triangle_material;
};

/// Loads every mesh of a model file (any format assimp reads) into one TriangleMesh, scaled by
/// `scale_to_mm`, with texture coordinates (channel 0) and the materials its triangles use (each
/// material's diffuse texture read with OpenCV, relative to the model file's folder). Throws
/// std::runtime_error naming the file if it is missing or unreadable, holds no triangles, or is
/// degenerate (zero extent or volume); naming the model file and the texture path when a texture
/// is missing, unreadable or embedded in the model file (not supported), or when a textured
/// material is used by faces without texture coordinates.
TriangleMesh LoadMesh(const std::string& path, double scale_to_mm);

/// Loads each mesh of a model file as a separate piece (e.g. the convex pieces of a
/// `*_collision.obj`), scaled by `scale_to_mm`; materials are not read (left empty). Throws as
/// LoadMesh does for the geometry.
std::vector<TriangleMesh> LoadMeshPieces(const std::string& path, double scale_to_mm);

/// Edges (between vertices at the same position: hard edges split vertices) that do not border
/// exactly two triangles: 0 for a closed solid; a cut-off or damaged file has some.
int64_t OpenEdges(const TriangleMesh& mesh);

/// Throws naming `what` (the file) unless `mesh` is a closed solid a part can be made of: every
/// edge borders exactly two triangles (see OpenEdges). LoadMesh already refused non-finite
/// vertices, flat meshes and meshes without volume.
void CheckClosedSolid(const std::string& what, const TriangleMesh& mesh);

/// Signed volume enclosed by the triangles, mm^3 (positive when wound outward).
double SignedVolume(const TriangleMesh& mesh);

/// Axis-aligned bounds of the vertices, mm (empty for a mesh without vertices).
Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh);

/// A square of side `size_mm` in the z = 0 plane, centred at the origin, normal +z: open, so a
/// renderer draws it two-sided (a table under the bin).
TriangleMesh MakeSquareMesh(float size_mm);

/// An open box standing on z = 0 with its inner floor centred at the origin: floor and four walls
/// of thickness `wall_mm` around an inner space of length (x) x width (y) x height (z), mm.
TriangleMesh MakeOpenBinMesh(double inner_length_mm, double inner_width_mm, double inner_height_mm,
                             double wall_mm);

}  // namespace stackgen
