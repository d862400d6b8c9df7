#pragma once

// What the renderer's own files share (renderer.cc, renderer_pbr.cc, renderer_silhouettes.cc,
// renderer_internal.cc): the GL state of a Renderer (Renderer::Impl), its uploaded meshes and
// programs, the texture units, shadow biases and helpers. Not for use outside gen/render/.

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "gen/render/egl_context.h"
#include "gen/render/renderer.h"

namespace stackgen {
namespace render_internal {

inline constexpr int kObjectsPerSilhouettePass = 32;  // one bit each in an R32UI target

// texture units: a material's texture, the shadow maps, the DFG table, the environment, one to
// set up textures on
inline constexpr int kMaterialTextureUnit = 0;
inline constexpr int kShadowMapUnit = 1;
inline constexpr int kDfgUnit = 2;
inline constexpr int kEnvironmentUnit = 3;
inline constexpr int kSetupUnit = 4;
inline constexpr int kResolveCoverageUnit = 5;  // the coverage pass's samples
inline constexpr int kShadowDepthUnit = 6;      // the shadow maps' depths, not compared
inline constexpr int kDfgSize = 32;             // texels per side of the DFG table

// shadow bias against acne, small enough for no visible gap between a shadow and its caster
// (tests: a 1 mm plate 1 mm above a floor): the depth pass pushes each triangle back by
// kShadowSlopeBias times its depth slope per texel (the filtered taps reach 1.5 texels) plus
// kShadowUnitsBias units; the scene pass looks up kShadowNormalOffsetTexels texels off the
// surface (scaled by the sine of the light's incidence) and kShadowDepthBiasMm nearer
inline constexpr float kShadowSlopeBias = 2.5f;
inline constexpr float kShadowUnitsBias = 4.f;
inline constexpr double kShadowNormalOffsetTexels = 1.0;
inline constexpr double kShadowDepthBiasMm = 0.05;
// a point light's map covers at most this half angle; surfaces outside it are lit
inline constexpr double kMaxShadowHalfAngleRad = 80 * M_PI / 180;

GLuint CompileShader(GLenum type, const std::string& source, const char* name);

GLuint LinkProgram(const std::string& vertex_source, const std::string& fragment_source,
                   const char* name);

std::string FramebufferStatusName(GLenum status);

void CheckFramebuffer(const char* name);

// (re)allocates `mat` as a continuous rows x cols image of `type` unless it already is one
void EnsureImage(cv::Mat* mat, int rows, int cols, int type);

void ValidateCamera(const CameraModel& camera);

// true when the mesh is a union of closed surfaces wound counter-clockwise seen from outside:
// with vertices welded by position, every edge is used as often in one direction as in the other,
// and every connected piece encloses a positive volume. Back faces of such a mesh never show.
bool IsClosedAndOutward(const TriangleMesh& mesh);

// The axis-aligned box around `box`'s eight corners moved by `target_from_source`.
Eigen::AlignedBox3d TransformedBox(const Eigen::Isometry3d& target_from_source,
                                   const Eigen::AlignedBox3d& box);

// A right-handed rotation light_from_world whose z axis (third row) is `forward`, unit.
Eigen::Matrix3d LightFromWorldRotation(const Eigen::Vector3d& forward);

// How one light sees the scene for its shadow map.
struct ShadowView {
  Eigen::Matrix4d clip_from_world;  // GL clip coordinates of the light's depth pass
  double depth_bias = 0;            // kShadowDepthBiasMm in map depth units (at the box centre)
  double normal_offset_mm = 0;      // kShadowNormalOffsetTexels in mm (at the far side)
  // the light's depth range, mm from the light (orthographic: along it, from the box centre's
  // plane) and the map's half width: mm (orthographic) or the tangent of its half angle
  bool perspective = false;
  double near_mm = 0, far_mm = 0;
  double half_width = 1;
};

// The view of `light` covering `box` (world, mm) with a map of `size` texels per side:
// orthographic along a directional light, a perspective from a point light aimed at the box
// centre. The light frame is right-handed with z forward and clip x, y growing with light x, y,
// like the camera's, so triangles keep their winding (front faces stay front faces).
ShadowView MakeShadowView(const Light& light, const Eigen::AlignedBox3d& box, int size);

// an sRGB display value (0..1) in linear light
float SrgbToLinear(float c);

// the GGX roughness whose lobe is as wide as a Blinn-Phong lobe of this exponent: Beckmann's
// alpha^2 = 2 / (n + 2), roughness = sqrt(alpha)
float RoughnessOfShininess(float shininess);

// Anti-aliasing by subpixel reconstruction (Chajdas, McGuire and Luebke, "Subpixel
// Reconstruction Antialiasing", I3D 2011): colour is shaded once per pixel, at its centre
// (`colors`, the surface there in `surfaces`, item index + 1, 0 = nothing), and a multisampled
// pass says which surface each of `samples` samples sees (`sample_surfaces`, four per pixel,
// at `positions` within the pixel, x and y in 0..1 along the image's columns and rows). A sample
// on the pixel's own surface takes the pixel's colour; one on another surface takes the colour
// of the nearest pixel whose centre shows that surface, the neighbours on the sample's side
// first; the pixel is the mean of its samples, as a multisample resolve would make it. Pixels
// whose samples all see their own surface (nearly all) keep their colour exactly. `colors` is
// resolved in place (edge pixels found first, written after, so every pixel reads centres);
// `edges` is working memory.
void ResolveEdges(const cv::Mat& surfaces, const cv::Mat& sample_surfaces, int samples,
                  const GLfloat* positions, cv::Mat* colors_in_out,
                  std::vector<std::vector<std::pair<int, cv::Vec3f>>>* edges);

}  // namespace render_internal

// one uploaded mesh
struct MeshBuffers {
  GLuint vertex_array = 0;
  GLuint vertex_buffer = 0;  // interleaved position (mm), normal, uv: 8 floats per vertex
  GLuint index_buffer = 0;
  GLsizei index_count = 0;
  bool cull_back_faces = false;  // closed and wound outwards (IsClosedAndOutward)
  bool has_uvs = false;          // texture coordinates uploaded (otherwise zeros)
  Eigen::AlignedBox3d bounds;    // object frame, mm
  // the mesh's own materials, and its triangles grouped by material: range k draws
  // range_counts[k] indices from range_firsts[k] with materials[range_materials[k]]
  std::vector<Material> materials;
  std::vector<GLsizei> range_firsts;
  std::vector<GLsizei> range_counts;
  std::vector<int> range_materials;
};

// uniform locations shared by both kinds of program
struct ProjectionUniforms {
  GLint camera_from_object = -1;
  GLint projection = -1;
  GLint depth_coefficients = -1;

  void Find(GLuint program) {
    camera_from_object = glGetUniformLocation(program, "camera_from_object");
    projection = glGetUniformLocation(program, "projection");
    depth_coefficients = glGetUniformLocation(program, "depth_coefficients");
  }
};

struct FrameUniforms;

// uniform locations of the lights and shadow maps, shared by both kinds of scene program
struct LightUniforms {
  GLint light_vector_camera = -1;
  GLint shadow_from_camera = -1;
  GLint shadow_normal_offset_mm = -1;
  GLint shadow_depth_bias = -1;
  GLint shadow_texel = -1;
  GLint shadow_softness = -1;

  void Find(GLuint program) {
    shadow_softness = glGetUniformLocation(program, "shadow_softness");
    light_vector_camera = glGetUniformLocation(program, "light_vector_camera");
    shadow_from_camera = glGetUniformLocation(program, "shadow_from_camera");
    shadow_normal_offset_mm = glGetUniformLocation(program, "shadow_normal_offset_mm");
    shadow_depth_bias = glGetUniformLocation(program, "shadow_depth_bias");
    shadow_texel = glGetUniformLocation(program, "shadow_texel");
  }
  // the frame's light vectors and, with shadows, the maps' transforms and biases
  void Set(const FrameUniforms& f) const;
};

// the scene program for one number of lights, with or without shadows and texture
struct ShadingProgram {
  GLuint program = 0;  // 0 until first used
  ProjectionUniforms projection;
  GLint instance_id = -1;
  GLint material_color_linear = -1;
  GLint material_specular = -1;
  GLint material_shininess = -1;
  LightUniforms lights;
  GLint light_terms = -1;
  uint64_t frame = 0;              // the Render call its per-frame uniforms were set for
  const DrawItem* item = nullptr;  // the item its per-item uniforms were set for, this frame
};

// the physically based colour program for one number of lights, with or without shadows,
// texture and environment
struct PbrProgram {
  GLuint program = 0;  // 0 until first used
  ProjectionUniforms projection;
  GLint base_color_linear = -1;
  GLint metallic = -1;
  GLint roughness = -1;
  GLint dielectric_f0 = -1;
  LightUniforms lights;
  GLint light_irradiance = -1;
  GLint environment_from_camera = -1;
  GLint environment_max_lod = -1;
  GLint irradiance_sh = -1;
  GLint environment_intensity = -1;
  GLint instance_id = -1;
  GLint surface_id = -1;
  GLint detail_frame = -1;
  GLint detail_kind = -1;
  GLint detail_strength = -1;
  GLint projector_camera = -1;
  uint64_t frame = 0;              // the Render call its per-frame uniforms were set for
  const DrawItem* item = nullptr;  // the item its pose was set for, this frame
};

// one uploaded environment
struct EnvironmentTexture {
  GLuint texture = 0;  // RGB16F octahedral, level k prefiltered for roughness k / (n - 1)
  std::array<Eigen::Vector3f, 9> irradiance_sh;
};

// what every scene program of one Render gets
struct FrameUniforms {
  int light_count = 0;
  bool shadows = false;
  const EnvironmentTexture* environment = nullptr;  // none: no environment light
  float environment_from_camera[9] = {};            // column-major rotation
  float environment_intensity[3] = {0, 0, 0};  // the intensity times the environment's colour
  float light_irradiance[Renderer::kMaxLights][3] = {};  // physically based: pi x diffuse
  float light_vectors[Renderer::kMaxLights][4] = {};     // see scene.vert.glsl
  float light_terms[Renderer::kMaxLights][3] = {};
  float shadow_from_camera[Renderer::kMaxLights][16] = {};  // column-major
  float shadow_normal_offset_mm[Renderer::kMaxLights] = {};
  float shadow_depth_bias[Renderer::kMaxLights] = {};
  float shadow_texel = 0;
  // physically based, a light of some size: shadows softened (shadow_lookup.glsl), and per light
  // (perspective 0 or 1, near mm, far mm, texels per mm of occluder distance: ortho, or times the
  // receiver's distance from the light: perspective)
  bool soft_shadows = false;
  float shadow_softness[Renderer::kMaxLights][4] = {};
  bool projector = false;              // physically based: write the projector's return
  float projector_camera[3] = {0, 0, 0};  // the projector's position, camera frame, mm
};

struct Renderer::Impl {
  EglContext context;  // first member: destroyed last, taking every GL object with it
  std::vector<MeshBuffers> meshes;
  std::vector<GLuint> textures;  // by texture_id

  // by light count, shadows, texture (ProgramIndex)
  std::array<ShadingProgram, (kMaxLights + 1) * 4> shading;
  GLuint silhouette_program = 0;
  ProjectionUniforms silhouette_projection;
  GLint object_bit = -1;
  GLuint shadow_program = 0;  // built when first used
  GLint light_clip_from_object = -1;

  // scene framebuffer: colour RGBA8, instance R16UI, camera z R32F, depth buffer
  GLuint scene_framebuffer = 0;
  GLuint color_buffer = 0;
  GLuint instance_buffer = 0;
  GLuint camera_z_buffer = 0;
  GLuint depth_buffer = 0;
  // silhouette framebuffer: one bit per object, R32UI
  GLuint silhouette_framebuffer = 0;
  GLuint bits_buffer = 0;
  // silhouettes beyond the image: the image and a margin around it, R32UI, made when first used
  GLuint margin_framebuffer = 0;
  GLuint margin_buffer = 0;
  int margin_canvas_width = 0;
  int margin_canvas_height = 0;
  std::vector<uint32_t> margin_bits;
  int width = 0;
  int height = 0;
  bool culling = false;  // GL_CULL_FACE state
  // shadow maps: one depth layer per light, allocated when first needed
  GLuint shadow_framebuffer = 0;
  GLuint shadow_maps = 0;
  GLuint shadow_depth_sampler = 0;  // reads the maps' depths (soft shadows' occluder search)
  int shadow_map_size = 0;
  int shadow_map_layers = 0;

  // physically based frames: the programs, the DFG table, the environments;
  // a single-sampled framebuffer shading each pixel once (colour, id, camera z, surface), and
  // when anti-aliased a multisampled coverage pass and its resolve (resolve.frag.glsl)
  std::array<PbrProgram, (kMaxLights + 1) * 64> pbr;
  GLuint empty_vertex_array = 0;  // 0 until the first physically based frame
  GLuint dfg_texture = 0;
  std::vector<EnvironmentTexture> environments;
  GLuint shaded_framebuffer = 0;  // colour, instance, camera z, surface; the scene depth buffer
  GLuint shaded_texture = 0;      // RGBA16F linear colour
  GLuint surface_texture = 0;     // R16UI item index + 1
  GLuint return_texture = 0;      // R32F the projector's return (RenderOptions::projector_return)
  // RGBA16F the environment's share of the linear colour (RenderOptions::environment_occlusion_mm)
  GLuint environment_texture = 0;
  GLuint coverage_program = 0;
  ProjectionUniforms coverage_projection;
  GLint coverage_surface_id = -1;
  GLuint coverage_framebuffer = 0;
  GLuint coverage_texture = 0;                  // multisampled R16UI surface per sample
  GLuint coverage_depth_buffer = 0;             // multisampled depth
  std::array<GLuint, 5> resolve_programs = {};  // by sample count, built when first used
  GLuint resolve_framebuffer = 0;
  GLuint resolve_buffer = 0;  // RGBA16UI: the surfaces of a pixel's samples
  int pbr_width = 0;          // size of the textures above
  int pbr_height = 0;
  int coverage_samples = 0;  // samples of the coverage targets
  cv::Mat sample_surfaces;   // read-back of the resolve pass, CV_16UC4
  cv::Mat centre_surfaces;   // CV_16UC1
  std::vector<std::vector<std::pair<int, cv::Vec3f>>> edge_colors;  // ResolveEdges, by row
  cv::Mat half_colors;   // read-back of linear colour, CV_16FC4
  cv::Mat float_colors;  // CV_32FC4
  cv::Mat environment_visibility;  // EnvironmentVisibility, CV_32FC1

  // per Render call
  uint64_t frame = 0;
  const CameraModel* frame_camera = nullptr;
  FrameUniforms frame_uniforms;
  GLuint bound_texture = 0;  // on kMaterialTextureUnit
  std::array<render_internal::ShadowView, kMaxLights> shadow_views;

  // reused between calls
  std::vector<std::pair<double, size_t>> draw_order;  // (camera z, item index), near first
  std::vector<uint32_t> bits;                         // silhouette read-back
  std::vector<const DrawItem*> objects;               // items with instance_id > 0
  std::vector<uint8_t*> mask_data;

  Impl(int width, int height);
  static int ProgramIndex(int light_count, bool shadows, bool textured) {
    return light_count * 4 + (shadows ? 2 : 0) + (textured ? 1 : 0);
  }
  ShadingProgram& Shading(int light_count, bool shadows, bool textured);
  ShadingProgram& UseShading(bool textured);
  PbrProgram& Pbr(int light_count, bool shadows, bool textured, bool environment, bool detailed,
                  bool projector, bool soft);
  PbrProgram& UsePbr(bool textured, bool detailed);
  void EnsurePbrResources();
  void EnsurePbrTargets(int samples);
  GLuint ResolveProgram(int samples);
  void DrawPbrSurface(const DrawItem& item, size_t index,
                      const Eigen::Isometry3d& camera_from_world, const MeshBuffers& mesh,
                      const Material& material, GLsizei first, GLsizei count);
  void ReadLinearColor(cv::Mat* color);
  // takes from result->color_linear the environment's light that what lies within radius_mm
  // of each surface hides (the environment's share read from its target, after ReadLinearColor)
  void OccludeEnvironment(const CameraModel& camera, float radius_mm, RenderResult* result);
  void CompositeBackground(const RenderOptions& options, RenderResult* result);
  void RenderPbr(const CameraModel& camera, const RenderOptions& options,
                 const std::vector<DrawItem>& items, RenderResult* result);
  // RenderPbr with MSAA: the surface each of `samples` samples sees (a cheap multisampled pass),
  // resolved four to a texel into sample_surfaces, each centre's surface into centre_surfaces,
  // and the sample positions into `positions` (2 per sample); leaves the shaded framebuffer bound
  void ReadSampleSurfaces(const CameraModel& camera, const std::vector<DrawItem>& items,
                          int samples, const Eigen::Isometry3d& camera_from_world,
                          GLfloat* positions);
  // Render's parts: its options checked (max_samples and description: the GL's, for PBR), the
  // lights and shadow maps set for the frame, and the Blinn-Phong pass read back
  void CheckOptions(const CameraModel& camera, const std::vector<Light>& lights,
                    const RenderOptions& options, int max_samples,
                    const std::string& description) const;
  void SetLights(const Eigen::Isometry3d& camera_from_world, const std::vector<Light>& lights,
                 bool shadows, const std::vector<DrawItem>& items);
  void SetShadows(const CameraModel& camera, const std::vector<Light>& lights, int shadow_map_size,
                  const std::vector<DrawItem>& items);
  void RenderPhong(const CameraModel& camera, const RenderOptions& options,
                   const std::vector<DrawItem>& items, const Eigen::Isometry3d& camera_from_world,
                   RenderResult* result);
  void Resize(int new_width, int new_height);
  void Validate(const CameraModel& camera, const std::vector<DrawItem>& items) const;
  void ValidateMaterial(const Material& material, const MeshBuffers& mesh,
                        const std::string& what) const;
  void SetProjection(const ProjectionUniforms& uniforms, const CameraModel& camera) const;
  void DrawSilhouetteBits(const CameraModel& camera, const std::vector<const DrawItem*>& to_draw,
                          std::vector<uint32_t>* read_back,
                          const std::function<void(size_t first, size_t count)>& spread);
  void RenderBeyond(const CameraModel& camera, const std::vector<cv::Mat>& masks,
                    std::vector<cv::Mat>* beyond);
  void SetCameraFromObject(const ProjectionUniforms& uniforms,
                           const Eigen::Isometry3d& camera_from_world, const DrawItem& item) const;
  void Draw(const MeshBuffers& mesh);
  void Draw(const MeshBuffers& mesh, GLsizei first, GLsizei count);
  void DrawSurface(const DrawItem& item, const Eigen::Isometry3d& camera_from_world,
                   const MeshBuffers& mesh, const Material& material, GLsizei first, GLsizei count);
  // Calls draw(item, index, mesh, material, first, count) for every surface of `items` in
  // draw_order (near items first): an item's own material over its whole mesh, or each material
  // range of its mesh with that material.
  template <typename DrawFn>
  void ForEachSurface(const std::vector<DrawItem>& items, DrawFn&& draw) const {
    for (const auto& [z, index] : draw_order) {
      const DrawItem& item = items[index];
      const MeshBuffers& mesh = meshes[item.mesh_id];
      if (!item.use_mesh_materials || mesh.materials.empty()) {
        draw(item, index, mesh, item.material, 0, mesh.index_count);
        continue;
      }
      for (size_t k = 0; k < mesh.range_firsts.size(); ++k) {
        draw(item, index, mesh, mesh.materials[mesh.range_materials[k]], mesh.range_firsts[k],
             mesh.range_counts[k]);
      }
    }
  }
  Eigen::AlignedBox3d WorldBounds(const std::vector<DrawItem>& items) const;
  void EnsureShadowMaps(int size, int layers);
  void RenderShadowMaps(const std::vector<Light>& lights, int size,
                        const std::vector<DrawItem>& items);
};

}  // namespace stackgen
