#include "gen/render/renderer.h"

#include "gen/render/renderer_internal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "shaders.h"

namespace stackgen {

// The shaders (gen/render/shaders/). Both the scene and the silhouette programs compute
// gl_Position with projection.glsl and `invariant`, so a silhouette covers exactly the pixels the
// object covers in the scene pass.
using namespace shaders;
using namespace render_internal;

Renderer::Impl::Impl(int width, int height) {
  if (width <= 0 || height <= 0) {
    throw std::runtime_error("Renderer: size " + std::to_string(width) + "x" +
                             std::to_string(height) + " is not positive");
  }
  // the silhouette program; scene and shadow programs are built when first used
  silhouette_program =
      LinkProgram(std::string("#version 330 core\n") + projection_glsl + silhouette_vert_glsl,
                  silhouette_frag_glsl, "silhouette program");
  silhouette_projection.Find(silhouette_program);
  object_bit = glGetUniformLocation(silhouette_program, "object_bit");

  // framebuffers; every output location i goes to colour attachment i
  glGenRenderbuffers(1, &color_buffer);
  glGenRenderbuffers(1, &instance_buffer);
  glGenRenderbuffers(1, &camera_z_buffer);
  glGenRenderbuffers(1, &depth_buffer);
  glGenRenderbuffers(1, &bits_buffer);
  glGenFramebuffers(1, &scene_framebuffer);
  glGenFramebuffers(1, &silhouette_framebuffer);
  Resize(width, height);
  glBindFramebuffer(GL_FRAMEBUFFER, scene_framebuffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, color_buffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_RENDERBUFFER, instance_buffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT2, GL_RENDERBUFFER, camera_z_buffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_buffer);
  const GLenum scene_draw_buffers[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1,
                                       GL_COLOR_ATTACHMENT2};
  glDrawBuffers(3, scene_draw_buffers);
  CheckFramebuffer("scene framebuffer");
  glBindFramebuffer(GL_FRAMEBUFFER, silhouette_framebuffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, bits_buffer);
  const GLenum silhouette_draw_buffers[] = {GL_COLOR_ATTACHMENT0};
  glDrawBuffers(1, silhouette_draw_buffers);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  CheckFramebuffer("silhouette framebuffer");

  // fixed state: tight rows on read-back and upload, no blending; image rows run down the
  // framebuffer, so a triangle counter-clockwise seen from outside is clockwise in window
  // coordinates
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glDisable(GL_BLEND);
  glDisable(GL_CULL_FACE);
  glFrontFace(GL_CW);
  glCullFace(GL_BACK);
  glDisable(GL_DITHER);
  glDepthFunc(GL_LESS);
  glLogicOp(GL_OR);
  glPolygonOffset(kShadowSlopeBias, kShadowUnitsBias);
  CheckGlError("Renderer: set-up");
}

void Renderer::Impl::Resize(int new_width, int new_height) {
  if (new_width == width && new_height == height) return;
  GLint max_size = 0;
  glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &max_size);
  if (new_width > max_size || new_height > max_size) {
    throw std::runtime_error("Renderer: size " + std::to_string(new_width) + "x" +
                             std::to_string(new_height) + " exceeds GL_MAX_RENDERBUFFER_SIZE " +
                             std::to_string(max_size));
  }
  const std::pair<GLuint, GLenum> storages[] = {{color_buffer, GL_RGBA8},
                                                {instance_buffer, GL_R16UI},
                                                {camera_z_buffer, GL_R32F},
                                                {depth_buffer, GL_DEPTH_COMPONENT32F},
                                                {bits_buffer, GL_R32UI}};
  for (const auto& [buffer, format] : storages) {
    glBindRenderbuffer(GL_RENDERBUFFER, buffer);
    glRenderbufferStorage(GL_RENDERBUFFER, format, new_width, new_height);
  }
  CheckGlError("Renderer: glRenderbufferStorage");
  width = new_width;
  height = new_height;
  bits.resize(static_cast<size_t>(width) * height);
}

void Renderer::Impl::Validate(const CameraModel& camera, const std::vector<DrawItem>& items) const {
  ValidateCamera(camera);
  for (size_t i = 0; i < items.size(); ++i) {
    const int mesh_id = items[i].mesh_id;
    if (mesh_id < 0 || mesh_id >= static_cast<int>(meshes.size())) {
      throw std::runtime_error("Renderer: item " + std::to_string(i) + " has unknown mesh_id " +
                               std::to_string(mesh_id) + " (" + std::to_string(meshes.size()) +
                               " meshes added)");
    }
    const SurfaceDetail& detail = items[i].detail;
    if (!(detail.strength >= 0 && detail.strength <= 1) || !(detail.scale_mm > 0) ||
        !std::isfinite(detail.scale_mm) || !detail.offset.allFinite()) {
      throw std::runtime_error("Renderer: item " + std::to_string(i) + "'s detail strength " +
                               std::to_string(detail.strength) + " must be in 0..1, scale_mm " +
                               std::to_string(detail.scale_mm) + " positive, offset finite");
    }
  }
}

void Renderer::Impl::ValidateMaterial(const Material& material, const MeshBuffers& mesh,
                                      const std::string& what) const {
  if (material.texture_id < -1 || material.texture_id >= static_cast<int>(textures.size())) {
    throw std::runtime_error(what + " has unknown texture_id " +
                             std::to_string(material.texture_id) + " (" +
                             std::to_string(textures.size()) + " textures added)");
  }
  if (material.texture_id >= 0 && !mesh.has_uvs) {
    throw std::runtime_error(what + " has texture_id " + std::to_string(material.texture_id) +
                             " but its mesh has no texture coordinates (uvs)");
  }
}

void Renderer::Impl::SetProjection(const ProjectionUniforms& uniforms,
                                   const CameraModel& camera) const {
  const double w = camera.width;
  const double h = camera.height;
  const double n = camera.near_mm;
  const double f = camera.far_mm;
  glUniform4f(uniforms.projection, static_cast<float>(2 * camera.fx / w),
              static_cast<float>((2 * camera.cx + 1) / w - 1),
              static_cast<float>(2 * camera.fy / h),
              static_cast<float>((2 * camera.cy + 1) / h - 1));
  glUniform2f(uniforms.depth_coefficients, static_cast<float>((f + n) / (f - n)),
              static_cast<float>(-2 * f * n / (f - n)));
}

void Renderer::Impl::SetCameraFromObject(const ProjectionUniforms& uniforms,
                                         const Eigen::Isometry3d& camera_from_world,
                                         const DrawItem& item) const {
  // compose in double, hand float to GL (column-major, as GL expects)
  const Eigen::Matrix4f camera_from_object =
      (camera_from_world * item.world_from_object).matrix().cast<float>();
  glUniformMatrix4fv(uniforms.camera_from_object, 1, GL_FALSE, camera_from_object.data());
}

void Renderer::Impl::Draw(const MeshBuffers& mesh) { Draw(mesh, 0, mesh.index_count); }

void Renderer::Impl::Draw(const MeshBuffers& mesh, GLsizei first, GLsizei count) {
  if (mesh.cull_back_faces != culling) {
    culling = mesh.cull_back_faces;
    if (culling) {
      glEnable(GL_CULL_FACE);
    } else {
      glDisable(GL_CULL_FACE);
    }
  }
  glBindVertexArray(mesh.vertex_array);
  glDrawElements(GL_TRIANGLES, count, GL_UNSIGNED_INT,
                 reinterpret_cast<const void*>(static_cast<size_t>(first) * sizeof(uint32_t)));
}

void Renderer::Impl::DrawSurface(const DrawItem& item, const Eigen::Isometry3d& camera_from_world,
                                 const MeshBuffers& mesh, const Material& material, GLsizei first,
                                 GLsizei count) {
  // the program for this material, with the item's pose and id
  const bool textured = material.texture_id >= 0;
  ShadingProgram& s = UseShading(textured);
  if (s.item != &item) {
    SetCameraFromObject(s.projection, camera_from_world, item);
    glUniform1ui(s.instance_id, item.instance_id);
    s.item = &item;
  }

  // the material with the item's gain; colours are display values: gamma 2 back to linear
  const Eigen::Vector3f color =
      material.color.cwiseProduct(item.gain.color).cwiseMax(0.f).cwiseMin(1.f);
  const Eigen::Vector3f color_linear = color.cwiseProduct(color);
  glUniform3fv(s.material_color_linear, 1, color_linear.data());
  glUniform1f(s.material_specular, material.specular * item.gain.specular);
  glUniform1f(s.material_shininess, material.shininess * item.gain.shininess);
  if (textured && textures[material.texture_id] != bound_texture) {
    bound_texture = textures[material.texture_id];
    glBindTexture(GL_TEXTURE_2D, bound_texture);
  }
  Draw(mesh, first, count);
}

Eigen::AlignedBox3d Renderer::Impl::WorldBounds(const std::vector<DrawItem>& items) const {
  Eigen::AlignedBox3d box;
  for (const DrawItem& item : items) {
    if (item.casts_shadow) {
      box.extend(TransformedBox(item.world_from_object, meshes[item.mesh_id].bounds));
    }
  }
  return box;
}

void Renderer::Impl::EnsureShadowMaps(int size, int layers) {
  if (shadow_program == 0) {
    shadow_program = LinkProgram(shadow_vert_glsl, shadow_frag_glsl, "shadow program");
    light_clip_from_object = glGetUniformLocation(shadow_program, "light_clip_from_object");
    glGenFramebuffers(1, &shadow_framebuffer);
    glGenTextures(1, &shadow_maps);
    glBindFramebuffer(GL_FRAMEBUFFER, shadow_framebuffer);
    glDrawBuffer(GL_NONE);
    glReadBuffer(GL_NONE);
  }
  if (size == shadow_map_size && layers <= shadow_map_layers) return;

  // depth layers compared on lookup, filtered 2 x 2
  GLint max_size = 0;
  glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
  if (size > max_size) {
    throw std::runtime_error("Renderer::Render: shadow_map_size " + std::to_string(size) +
                             " exceeds GL_MAX_TEXTURE_SIZE " + std::to_string(max_size));
  }
  glActiveTexture(GL_TEXTURE0 + kShadowMapUnit);
  glBindTexture(GL_TEXTURE_2D_ARRAY, shadow_maps);
  glTexImage3D(GL_TEXTURE_2D_ARRAY, 0, GL_DEPTH_COMPONENT32F, size, size, layers, 0,
               GL_DEPTH_COMPONENT, GL_FLOAT, nullptr);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
  glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
  glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  CheckGlError("Renderer::Render: shadow map storage");
  shadow_map_size = size;
  shadow_map_layers = layers;
  glBindFramebuffer(GL_FRAMEBUFFER, shadow_framebuffer);
  glFramebufferTextureLayer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, shadow_maps, 0, 0);
  CheckFramebuffer("shadow framebuffer");
}

void Renderer::Impl::RenderShadowMaps(const std::vector<Light>& lights, int size,
                                      const std::vector<DrawItem>& items) {
  const int light_count = static_cast<int>(lights.size());
  EnsureShadowMaps(size, light_count);
  const Eigen::AlignedBox3d box = WorldBounds(items);

  // depth only, each light into its layer, pushed back by the slope-scaled bias
  glBindFramebuffer(GL_FRAMEBUFFER, shadow_framebuffer);
  glViewport(0, 0, size, size);
  glEnable(GL_DEPTH_TEST);
  glEnable(GL_POLYGON_OFFSET_FILL);
  glUseProgram(shadow_program);
  const GLfloat far_depth = 1;
  for (int i = 0; i < light_count; ++i) {
    shadow_views[i] = MakeShadowView(lights[i], box, size);
    glFramebufferTextureLayer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, shadow_maps, 0, i);
    glClearBufferfv(GL_DEPTH, 0, &far_depth);
    for (const DrawItem& item : items) {
      if (!item.casts_shadow) continue;
      const Eigen::Matrix4f clip_from_object =
          (shadow_views[i].clip_from_world * item.world_from_object.matrix()).cast<float>();
      glUniformMatrix4fv(light_clip_from_object, 1, GL_FALSE, clip_from_object.data());
      Draw(meshes[item.mesh_id]);
    }
  }
  glBindVertexArray(0);
  glDisable(GL_POLYGON_OFFSET_FILL);
  CheckGlError("Renderer::Render: shadow pass");
}

Renderer::Renderer(int width, int height) : impl_(std::make_unique<Impl>(width, height)) {}

Renderer::~Renderer() = default;

int Renderer::AddTexture(const cv::Mat& rgb) {
  if (rgb.empty() || rgb.type() != CV_8UC3) {
    throw std::runtime_error("Renderer::AddTexture: need a non-empty CV_8UC3 RGB image, got " +
                             std::to_string(rgb.cols) + "x" + std::to_string(rgb.rows) +
                             " of OpenCV type " + std::to_string(rgb.type()));
  }
  impl_->context.MakeCurrent();
  GLint max_size = 0;
  glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
  if (rgb.cols > max_size || rgb.rows > max_size) {
    throw std::runtime_error("Renderer::AddTexture: size " + std::to_string(rgb.cols) + "x" +
                             std::to_string(rgb.rows) + " exceeds GL_MAX_TEXTURE_SIZE " +
                             std::to_string(max_size));
  }

  // rows as they are: texture row t = 0 is image row 0, the top (the shader flips v)
  GLuint texture = 0;
  glGenTextures(1, &texture);
  glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  glBindTexture(GL_TEXTURE_2D, texture);
  glPixelStorei(GL_UNPACK_ROW_LENGTH, static_cast<GLint>(rgb.step[0] / rgb.elemSize()));
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB8, rgb.cols, rgb.rows, 0, GL_RGB, GL_UNSIGNED_BYTE,
               rgb.data);
  glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
  glGenerateMipmap(GL_TEXTURE_2D);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
  impl_->bound_texture = texture;
  CheckGlError("Renderer::AddTexture");
  impl_->textures.push_back(texture);
  return static_cast<int>(impl_->textures.size()) - 1;
}

int Renderer::AddEnvironment(const PrefilteredEnvironment& environment) {
  // check the levels: 2:1, each half the one before, linear RGB floats
  constexpr int kLevels = PrefilteredEnvironment::kLevels;
  const std::string what = "Renderer::AddEnvironment: '" + environment.name + "'";
  if (environment.levels.size() != static_cast<size_t>(kLevels)) {
    throw std::runtime_error(what + " has " + std::to_string(environment.levels.size()) +
                             " levels, not " + std::to_string(kLevels));
  }
  for (int k = 0; k < kLevels; ++k) {
    const cv::Mat& level = environment.levels[k];
    const cv::Mat& base = environment.levels[0];
    if (level.type() != CV_32FC3 || level.cols != 2 * level.rows || level.rows == 0 ||
        level.cols != (base.cols >> k) || level.rows != (base.rows >> k) || !level.isContinuous()) {
      throw std::runtime_error(what + ": level " + std::to_string(k) + " is " +
                               std::to_string(level.cols) + "x" + std::to_string(level.rows) +
                               " of OpenCV type " + std::to_string(level.type()) +
                               ", not a continuous 2:1 CV_32FC3 image half the level before");
    }
  }

  // one texture, the levels as the mip chain of an octahedral map as wide as the equirectangular
  // one (more texels than it has), clamped at its edges
  impl_->context.MakeCurrent();
  EnvironmentTexture uploaded;
  uploaded.irradiance_sh = environment.irradiance_sh;
  glGenTextures(1, &uploaded.texture);
  glActiveTexture(GL_TEXTURE0 + kEnvironmentUnit);
  glBindTexture(GL_TEXTURE_2D, uploaded.texture);
  for (int k = 0; k < kLevels; ++k) {
    const cv::Mat& level = environment.levels[k];
    const cv::Mat octahedral = OctahedralOf(level, level.cols);
    glTexImage2D(GL_TEXTURE_2D, k, GL_RGB16F, octahedral.cols, octahedral.rows, 0, GL_RGB, GL_FLOAT,
                 octahedral.data);
  }
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_BASE_LEVEL, 0);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, kLevels - 1);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  CheckGlError("Renderer::AddEnvironment");
  impl_->environments.push_back(uploaded);
  return static_cast<int>(impl_->environments.size()) - 1;
}

namespace {

// Throws unless `mesh` can be uploaded: triangles, a normal (and a uv, if any) per position,
// indices in range, a material per triangle when it has materials, CV_8UC3 textures with uvs.
void CheckMeshForGl(const TriangleMesh& mesh) {
  const size_t vertex_count = mesh.positions_mm.size();
  if (mesh.triangles.empty()) throw std::runtime_error("Renderer::AddMesh: mesh has no triangles");
  if (mesh.normals.size() != vertex_count) {
    throw std::runtime_error("Renderer::AddMesh: " + std::to_string(mesh.normals.size()) +
                             " normals for " + std::to_string(vertex_count) + " positions");
  }
  if (!mesh.uvs.empty() && mesh.uvs.size() != vertex_count) {
    throw std::runtime_error("Renderer::AddMesh: " + std::to_string(mesh.uvs.size()) + " uvs for " +
                             std::to_string(vertex_count) + " positions");
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (const uint32_t index : mesh.triangles[t]) {
      if (index >= vertex_count) {
        throw std::runtime_error("Renderer::AddMesh: triangle " + std::to_string(t) +
                                 " has index " + std::to_string(index) + " >= vertex count " +
                                 std::to_string(vertex_count));
      }
    }
  }

  // check the materials
  const size_t material_count = mesh.materials.size();
  const size_t expected_triangle_materials = material_count > 0 ? mesh.triangles.size() : 0;
  if (mesh.triangle_material.size() != expected_triangle_materials) {
    throw std::runtime_error("Renderer::AddMesh: " + std::to_string(mesh.triangle_material.size()) +
                             " triangle materials for " + std::to_string(mesh.triangles.size()) +
                             " triangles and " + std::to_string(material_count) + " materials");
  }
  for (size_t t = 0; t < mesh.triangle_material.size(); ++t) {
    if (mesh.triangle_material[t] < 0 ||
        mesh.triangle_material[t] >= static_cast<int>(material_count)) {
      throw std::runtime_error("Renderer::AddMesh: triangle " + std::to_string(t) +
                               " has material " + std::to_string(mesh.triangle_material[t]) +
                               " of " + std::to_string(material_count));
    }
  }
  for (const MeshMaterial& material : mesh.materials) {
    if (material.texture.empty()) continue;
    const std::string what = "Renderer::AddMesh: material '" + material.name + "' texture '" +
                             material.texture_path + "'";
    if (material.texture.type() != CV_8UC3) {
      throw std::runtime_error(what + " is not CV_8UC3 (OpenCV type " +
                               std::to_string(material.texture.type()) + ")");
    }
    if (mesh.uvs.empty()) throw std::runtime_error(what + ": the mesh has no texture coordinates");
  }
}

// Position, normal and texture coordinate of each vertex, interleaved (8 floats).
std::vector<float> InterleavedVertices(const TriangleMesh& mesh) {
  const size_t vertex_count = mesh.positions_mm.size();
  std::vector<float> vertices;
  vertices.reserve(vertex_count * 8);
  for (size_t i = 0; i < vertex_count; ++i) {
    vertices.insert(vertices.end(), mesh.positions_mm[i].data(), mesh.positions_mm[i].data() + 3);
    vertices.insert(vertices.end(), mesh.normals[i].data(), mesh.normals[i].data() + 3);
    const Eigen::Vector2f uv = mesh.uvs.empty() ? Eigen::Vector2f::Zero() : mesh.uvs[i];
    vertices.insert(vertices.end(), uv.data(), uv.data() + 2);
  }
  return vertices;
}

// The triangles grouped by material, in their order within each group; each group's range and
// material go into `buffers`.
std::vector<std::array<uint32_t, 3>> TrianglesByMaterial(const TriangleMesh& mesh,
                                                         MeshBuffers* buffers) {
  const size_t material_count = mesh.materials.size();
  std::vector<std::array<uint32_t, 3>> triangles;
  if (material_count == 0) {
    triangles = mesh.triangles;
  } else {
    triangles.reserve(mesh.triangles.size());
    for (size_t m = 0; m < material_count; ++m) {
      const GLsizei first = static_cast<GLsizei>(triangles.size() * 3);
      for (size_t t = 0; t < mesh.triangles.size(); ++t) {
        if (mesh.triangle_material[t] == static_cast<int>(m)) {
          triangles.push_back(mesh.triangles[t]);
        }
      }
      const GLsizei count = static_cast<GLsizei>(triangles.size() * 3) - first;
      if (count == 0) continue;
      buffers->range_firsts.push_back(first);
      buffers->range_counts.push_back(count);
      buffers->range_materials.push_back(static_cast<int>(m));
    }
  }
  return triangles;
}

}  // namespace

int Renderer::AddMesh(const TriangleMesh& mesh) {
  static_assert(sizeof(std::array<uint32_t, 3>) == 3 * sizeof(uint32_t), "packed triangles");
  CheckMeshForGl(mesh);
  const std::vector<float> vertices = InterleavedVertices(mesh);
  MeshBuffers buffers;
  const std::vector<std::array<uint32_t, 3>> triangles = TrianglesByMaterial(mesh, &buffers);

  // the materials, each texture uploaded once
  std::map<const uint8_t*, int> texture_ids;
  for (const MeshMaterial& source : mesh.materials) {
    Material material;
    material.color = source.color;
    material.specular = source.specular;
    material.shininess = source.shininess;
    material.metallic = source.metallic;
    material.roughness = source.roughness;
    material.metal_color = source.metal_color;
    if (!source.texture.empty()) {
      const auto found = texture_ids.find(source.texture.data);
      material.texture_id = found != texture_ids.end() ? found->second : AddTexture(source.texture);
      texture_ids[source.texture.data] = material.texture_id;
    }
    buffers.materials.push_back(material);
  }

  // upload once into a vertex array of its own
  impl_->context.MakeCurrent();
  glGenVertexArrays(1, &buffers.vertex_array);
  glGenBuffers(1, &buffers.vertex_buffer);
  glGenBuffers(1, &buffers.index_buffer);
  glBindVertexArray(buffers.vertex_array);
  glBindBuffer(GL_ARRAY_BUFFER, buffers.vertex_buffer);
  glBufferData(GL_ARRAY_BUFFER, vertices.size() * sizeof(float), vertices.data(), GL_STATIC_DRAW);
  glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, buffers.index_buffer);
  glBufferData(GL_ELEMENT_ARRAY_BUFFER, triangles.size() * sizeof(triangles[0]), triangles.data(),
               GL_STATIC_DRAW);
  constexpr GLsizei kStride = 8 * sizeof(float);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, kStride, nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, kStride,
                        reinterpret_cast<const void*>(3 * sizeof(float)));
  glEnableVertexAttribArray(2);
  glVertexAttribPointer(2, 2, GL_FLOAT, GL_FALSE, kStride,
                        reinterpret_cast<const void*>(6 * sizeof(float)));
  glBindVertexArray(0);
  buffers.index_count = static_cast<GLsizei>(triangles.size() * 3);
  buffers.cull_back_faces = IsClosedAndOutward(mesh);
  buffers.has_uvs = !mesh.uvs.empty();
  buffers.bounds = Bounds(mesh);
  CheckGlError("Renderer::AddMesh");
  impl_->meshes.push_back(std::move(buffers));
  return static_cast<int>(impl_->meshes.size()) - 1;
}

RenderResult Renderer::Render(const CameraModel& camera, const std::vector<Light>& lights,
                              const RenderOptions& options, const std::vector<DrawItem>& items) {
  RenderResult result;
  Render(camera, lights, options, items, &result);
  return result;
}

void Renderer::Impl::CheckOptions(const CameraModel& camera, const std::vector<Light>& lights,
                                  const RenderOptions& options, int max_samples,
                                  const std::string& description) const {
  if (lights.size() > static_cast<size_t>(kMaxLights)) {
    throw std::runtime_error("Renderer::Render: " + std::to_string(lights.size()) +
                             " lights, at most " + std::to_string(kMaxLights));
  }
  if (!options.background_image.empty() &&
      (options.background_image.type() != CV_8UC3 ||
       options.background_image.size() != cv::Size(camera.width, camera.height))) {
    throw std::runtime_error("Renderer::Render: background_image must be CV_8UC3 of the camera's " +
                             std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                             ", got " + std::to_string(options.background_image.cols) + "x" +
                             std::to_string(options.background_image.rows) + " of OpenCV type " +
                             std::to_string(options.background_image.type()));
  }
  for (size_t i = 0; i < lights.size(); ++i) {
    if (!(lights[i].radius_rad >= 0 && lights[i].radius_rad <= kMaxLightRadiusRad)) {
      throw std::runtime_error("Renderer::Render: light " + std::to_string(i) + "'s radius_rad " +
                               std::to_string(lights[i].radius_rad) + " is outside 0.." +
                               std::to_string(kMaxLightRadiusRad));
    }
  }
  if (options.shadows && (options.shadow_map_size < kMinShadowMapSize ||
                          options.shadow_map_size > kMaxShadowMapSize)) {
    throw std::runtime_error("Renderer::Render: shadow_map_size " +
                             std::to_string(options.shadow_map_size) + " is outside " +
                             std::to_string(kMinShadowMapSize) + ".." +
                             std::to_string(kMaxShadowMapSize));
  }
  if (options.shading == Shading::kPbr) {
    const int samples = options.msaa_samples;
    if ((samples != 1 && samples != 2 && samples != 4) || samples > max_samples) {
      throw std::runtime_error("Renderer::Render: msaa_samples " + std::to_string(samples) +
                               " is not 1, 2 or 4 up to " + std::to_string(max_samples) +
                               ", the most this GL takes (" + description + ")");
    }
    if (options.environment_id < -1 ||
        options.environment_id >= static_cast<int>(environments.size())) {
      throw std::runtime_error("Renderer::Render: unknown environment_id " +
                               std::to_string(options.environment_id) + " (" +
                               std::to_string(environments.size()) + " environments added)");
    }
    if (!(options.environment_intensity >= 0) || !std::isfinite(options.environment_intensity) ||
        !(options.background_scale >= 0) || !std::isfinite(options.background_scale) ||
        !std::isfinite(options.environment_yaw_deg) || !options.environment_color.allFinite() ||
        !(options.environment_color.minCoeff() >= 0)) {
      throw std::runtime_error("Renderer::Render: environment_intensity " +
                               std::to_string(options.environment_intensity) +
                               ", environment_color and background_scale " +
                               std::to_string(options.background_scale) +
                               " must be finite and >= 0, environment_yaw_deg finite");
    }
    if (!(options.environment_occlusion_mm >= 0) ||
        !std::isfinite(options.environment_occlusion_mm)) {
      throw std::runtime_error("Renderer::Render: environment_occlusion_mm " +
                               std::to_string(options.environment_occlusion_mm) +
                               " must be finite and >= 0");
    }
    if (options.projector_return && !options.projector_position_mm.allFinite()) {
      throw std::runtime_error("Renderer::Render: projector_position_mm is not finite");
    }
  } else if (options.shading != Shading::kPhong) {
    throw std::runtime_error("Renderer::Render: unknown shading");
  } else if (options.projector_return) {
    throw std::runtime_error(
        "Renderer::Render: projector_return needs physically based shading (Shading::kPbr)");
  }
}

void Renderer::Impl::SetLights(const Eigen::Isometry3d& camera_from_world,
                               const std::vector<Light>& lights, bool shadows,
                               const std::vector<DrawItem>& items) {
  // lights in the camera frame: towards a directional light, the position of a point light
  FrameUniforms& frame = frame_uniforms;
  frame.light_count = static_cast<int>(lights.size());
  frame.shadows = shadows && !lights.empty() &&
                  std::any_of(items.begin(), items.end(),
                              [](const DrawItem& item) { return item.casts_shadow; });
  for (size_t i = 0; i < lights.size(); ++i) {
    const Light& light = lights[i];
    Eigen::Vector4d vector_camera;
    if (light.type == Light::Type::kDirectional) {
      const Eigen::Vector3d direction_camera =
          camera_from_world.linear() * light.direction_world.cast<double>();
      if (!(direction_camera.norm() > 0) || !direction_camera.allFinite()) {
        throw std::runtime_error("Renderer::Render: light " + std::to_string(i) +
                                 " has a zero or invalid direction_world");
      }
      vector_camera << -direction_camera.normalized(), 0;
    } else if (light.type == Light::Type::kPoint) {
      if (!light.position_world.allFinite()) {
        throw std::runtime_error("Renderer::Render: point light " + std::to_string(i) +
                                 " has an invalid position_world");
      }
      vector_camera << camera_from_world * light.position_world.cast<double>(), 1;
    } else {
      throw std::runtime_error("Renderer::Render: light " + std::to_string(i) +
                               " has an unknown type");
    }
    const Eigen::Vector4f v = vector_camera.cast<float>();
    std::memcpy(frame.light_vectors[i], v.data(), sizeof(frame.light_vectors[i]));
    frame.light_terms[i][0] = light.ambient;
    frame.light_terms[i][1] = light.diffuse;
    frame.light_terms[i][2] = light.specular;
    for (int c = 0; c < 3; ++c)
      frame.light_irradiance[i][c] = static_cast<float>(M_PI) * light.diffuse * light.color[c];
  }
}

// shadow maps, from each light over the box of all items
void Renderer::Impl::SetShadows(const CameraModel& camera, const std::vector<Light>& lights,
                                int shadow_map_size, const std::vector<DrawItem>& items) {
  RenderShadowMaps(lights, shadow_map_size, items);
  // from the camera frame to (s, t, depth) in [0, 1] of each map
  Eigen::Matrix4d texture_from_clip = 0.5 * Eigen::Matrix4d::Identity();
  texture_from_clip.topRightCorner<3, 1>().setConstant(0.5);
  texture_from_clip(3, 3) = 1;
  for (size_t i = 0; i < lights.size(); ++i) {
    const ShadowView& view = shadow_views[i];
    const Eigen::Matrix4f shadow_from_camera =
        (texture_from_clip * view.clip_from_world * camera.world_from_camera.matrix())
            .cast<float>();
    std::memcpy(frame_uniforms.shadow_from_camera[i], shadow_from_camera.data(),
                sizeof(frame_uniforms.shadow_from_camera[i]));
    frame_uniforms.shadow_normal_offset_mm[i] = static_cast<float>(view.normal_offset_mm);
    frame_uniforms.shadow_depth_bias[i] = static_cast<float>(view.depth_bias);
    // a shadow edge's half width in texels per mm between occluder and receiver: tan(radius)
    // over a texel's width in mm (perspective: at 1 mm from the light, divided by the
    // receiver's distance in the shader)
    float* softness = frame_uniforms.shadow_softness[i];
    softness[0] = view.perspective ? 1.f : 0.f;
    softness[1] = static_cast<float>(view.near_mm);
    softness[2] = static_cast<float>(view.far_mm);
    softness[3] = static_cast<float>(std::tan(static_cast<double>(lights[i].radius_rad)) *
                                     shadow_map_size / (2 * view.half_width));
  }
  frame_uniforms.shadow_texel = 1.f / static_cast<float>(shadow_map_size);
  glActiveTexture(GL_TEXTURE0 + kShadowMapUnit);
  glBindTexture(GL_TEXTURE_2D_ARRAY, shadow_maps);
  if (frame_uniforms.soft_shadows) {
    // the same maps read as plain depths, for the occluders' distance
    if (shadow_depth_sampler == 0) {
      glGenSamplers(1, &shadow_depth_sampler);
      glSamplerParameteri(shadow_depth_sampler, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
      glSamplerParameteri(shadow_depth_sampler, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
      glSamplerParameteri(shadow_depth_sampler, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
      glSamplerParameteri(shadow_depth_sampler, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
      glSamplerParameteri(shadow_depth_sampler, GL_TEXTURE_COMPARE_MODE, GL_NONE);
    }
    glActiveTexture(GL_TEXTURE0 + kShadowDepthUnit);
    glBindTexture(GL_TEXTURE_2D_ARRAY, shadow_maps);
    glBindSampler(kShadowDepthUnit, shadow_depth_sampler);
  }
  glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  CheckGlError("Renderer::Render: shadow maps");
}

void Renderer::Impl::RenderPhong(const CameraModel& camera, const RenderOptions& options,
                                 const std::vector<DrawItem>& items,
                                 const Eigen::Isometry3d& camera_from_world, RenderResult* result) {
  // clear: background colour, id 0, camera z 0, far depth
  Resize(camera.width, camera.height);
  glBindFramebuffer(GL_FRAMEBUFFER, scene_framebuffer);
  glViewport(0, 0, width, height);
  glDisable(GL_COLOR_LOGIC_OP);
  glEnable(GL_DEPTH_TEST);
  const Eigen::Vector3f& background_rgb = options.background_rgb;
  const GLfloat background[4] = {background_rgb.x(), background_rgb.y(), background_rgb.z(), 1};
  const GLuint zero_id[4] = {0, 0, 0, 0};
  const GLfloat zero_z[4] = {0, 0, 0, 0};
  const GLfloat far_depth = 1;
  glClearBufferfv(GL_COLOR, 0, background);
  glClearBufferuiv(GL_COLOR, 1, zero_id);
  glClearBufferfv(GL_COLOR, 2, zero_z);
  glClearBufferfv(GL_DEPTH, 0, &far_depth);

  // each material of a mesh (or the item's material) in one draw, near items first
  ForEachSurface(items, [&](const DrawItem& item, size_t, const MeshBuffers& mesh,
                            const Material& material, GLsizei first, GLsizei count) {
    DrawSurface(item, camera_from_world, mesh, material, first, count);
  });
  glBindVertexArray(0);

  // read back; framebuffer row 0 is image row 0 already (see projection.glsl)
  EnsureImage(&result->color, height, width, CV_8UC3);
  EnsureImage(&result->depth_mm, height, width, CV_32FC1);
  EnsureImage(&result->instance, height, width, CV_16UC1);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, result->color.data);
  glReadBuffer(GL_COLOR_ATTACHMENT1);
  glReadPixels(0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_SHORT, result->instance.data);
  glReadBuffer(GL_COLOR_ATTACHMENT2);
  glReadPixels(0, 0, width, height, GL_RED, GL_FLOAT, result->depth_mm.data);
  result->color_linear.release();
  result->projector_return.release();
  CheckGlError("Renderer::Render");

  // the background image where nothing was drawn (camera z 0), copied exactly
  if (!options.background_image.empty()) {
    for (int v = 0; v < height; ++v) {
      const float* depth = result->depth_mm.ptr<float>(v);
      const uint8_t* background_row = options.background_image.ptr<uint8_t>(v);
      uint8_t* color = result->color.ptr<uint8_t>(v);
      for (int u = 0; u < width; ++u) {
        if (depth[u] == 0.f) std::memcpy(color + 3 * u, background_row + 3 * u, 3);
      }
    }
  }
}

void Renderer::Render(const CameraModel& camera, const std::vector<Light>& lights,
                      const RenderOptions& options, const std::vector<DrawItem>& items,
                      RenderResult* result) {
  Impl& impl = *impl_;
  impl.context.MakeCurrent();
  impl.Validate(camera, items);
  const bool pbr = options.shading == Shading::kPbr;
  impl.CheckOptions(camera, lights, options, pbr ? MaxMsaaSamples() : 0,
                    pbr ? Description() : std::string());
  for (size_t i = 0; i < items.size(); ++i) {
    const MeshBuffers& mesh = impl.meshes[items[i].mesh_id];
    if (!items[i].use_mesh_materials || mesh.materials.empty()) {
      impl.ValidateMaterial(items[i].material, mesh,
                            "Renderer::Render: item " + std::to_string(i) + "'s material");
    }
  }
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();

  impl.SetLights(camera_from_world, lights, options.shadows, items);
  impl.frame_uniforms.soft_shadows =
      pbr && impl.frame_uniforms.shadows &&
      std::any_of(lights.begin(), lights.end(), [](const Light& l) { return l.radius_rad > 0; });
  if (impl.frame_uniforms.shadows) impl.SetShadows(camera, lights, options.shadow_map_size, items);

  // draw near items first so the depth test rejects hidden fragments before shading
  impl.draw_order.clear();
  for (size_t i = 0; i < items.size(); ++i) {
    const double z = (camera_from_world * items[i].world_from_object.translation()).z();
    impl.draw_order.emplace_back(z, i);
  }
  std::sort(impl.draw_order.begin(), impl.draw_order.end());

  // a new frame: each scene program gets its per-frame uniforms on first use
  ++impl.frame;
  impl.frame_camera = &camera;
  impl.bound_texture = 0;
  if (pbr) {
    // the environment turned about world z, seen from the camera
    FrameUniforms& frame = impl.frame_uniforms;
    frame.environment =
        options.environment_id >= 0 ? &impl.environments[options.environment_id] : nullptr;
    for (int c = 0; c < 3; ++c) {
      frame.environment_intensity[c] = options.environment_intensity * options.environment_color[c];
    }
    const Eigen::Matrix3f environment_from_camera =
        (Eigen::AngleAxisd(-options.environment_yaw_deg * M_PI / 180, Eigen::Vector3d::UnitZ())
             .toRotationMatrix() *
         camera.world_from_camera.linear())
            .cast<float>();
    std::memcpy(frame.environment_from_camera, environment_from_camera.data(),
                sizeof(frame.environment_from_camera));
    frame.projector = options.projector_return;
    const Eigen::Vector3f projector_camera =
        (camera_from_world * options.projector_position_mm).cast<float>();
    for (int c = 0; c < 3; ++c) frame.projector_camera[c] = projector_camera[c];
    impl.RenderPbr(camera, options, items, result);
    return;
  }

  impl.RenderPhong(camera, options, items, camera_from_world, result);
}

std::string Renderer::Description() const { return impl_->context.Description(); }

int Renderer::MaxMsaaSamples() const {
  impl_->context.MakeCurrent();
  GLint samples = 0;
  GLint integer_samples = 0;
  glGetIntegerv(GL_MAX_SAMPLES, &samples);
  glGetIntegerv(GL_MAX_INTEGER_SAMPLES, &integer_samples);
  return std::min(samples, integer_samples);
}

}  // namespace stackgen
