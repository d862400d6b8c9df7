#include "gen/render/renderer.h"

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

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <opencv2/imgproc.hpp>

#include "gen/render/egl_context.h"
#include "shaders.h"

namespace stackgen {
namespace {

// The shaders (gen/render/shaders/). Both the scene and the silhouette programs compute
// gl_Position with projection.glsl and `invariant`, so a silhouette covers exactly the pixels the
// object covers in the scene pass.
using namespace shaders;

constexpr int kObjectsPerSilhouettePass = 32;  // one bit each in an R32UI target

// texture units: a material's texture, the shadow maps, the DFG table, the environment, one to
// set up textures on
constexpr int kMaterialTextureUnit = 0;
constexpr int kShadowMapUnit = 1;
constexpr int kDfgUnit = 2;
constexpr int kEnvironmentUnit = 3;
constexpr int kSetupUnit = 4;
constexpr int kResolveCoverageUnit = 5;  // the coverage pass's samples
constexpr int kDfgSize = 32;             // texels per side of the DFG table

// shadow bias against acne, small enough for no visible gap between a shadow and its caster
// (tests: a 1 mm plate 1 mm above a floor): the depth pass pushes each triangle back by
// kShadowSlopeBias times its depth slope per texel (the filtered taps reach 1.5 texels) plus
// kShadowUnitsBias units; the scene pass looks up kShadowNormalOffsetTexels texels off the
// surface (scaled by the sine of the light's incidence) and kShadowDepthBiasMm nearer
constexpr float kShadowSlopeBias = 2.5f;
constexpr float kShadowUnitsBias = 4.f;
constexpr double kShadowNormalOffsetTexels = 1.0;
constexpr double kShadowDepthBiasMm = 0.05;
// a point light's map covers at most this half angle; surfaces outside it are lit
constexpr double kMaxShadowHalfAngleRad = 80 * M_PI / 180;

GLuint CompileShader(GLenum type, const std::string& source, const char* name) {
  const GLuint shader = glCreateShader(type);
  const char* text = source.c_str();
  glShaderSource(shader, 1, &text, nullptr);
  glCompileShader(shader);
  GLint ok = GL_FALSE;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (ok != GL_TRUE) {
    char log[4096] = {};
    glGetShaderInfoLog(shader, sizeof(log), nullptr, log);
    glDeleteShader(shader);
    throw std::runtime_error(std::string("glCompileShader failed (") + name + "): " + log);
  }
  return shader;
}

GLuint LinkProgram(const std::string& vertex_source, const std::string& fragment_source,
                   const char* name) {
  const GLuint vertex = CompileShader(GL_VERTEX_SHADER, vertex_source, name);
  const GLuint fragment = CompileShader(GL_FRAGMENT_SHADER, fragment_source, name);
  const GLuint program = glCreateProgram();
  glAttachShader(program, vertex);
  glAttachShader(program, fragment);
  glLinkProgram(program);
  glDeleteShader(vertex);
  glDeleteShader(fragment);
  GLint ok = GL_FALSE;
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (ok != GL_TRUE) {
    char log[4096] = {};
    glGetProgramInfoLog(program, sizeof(log), nullptr, log);
    glDeleteProgram(program);
    throw std::runtime_error(std::string("glLinkProgram failed (") + name + "): " + log);
  }
  CheckGlError(name);
  return program;
}

std::string FramebufferStatusName(GLenum status) {
  switch (status) {
    case GL_FRAMEBUFFER_COMPLETE:
      return "GL_FRAMEBUFFER_COMPLETE";
    case GL_FRAMEBUFFER_UNDEFINED:
      return "GL_FRAMEBUFFER_UNDEFINED";
    case GL_FRAMEBUFFER_INCOMPLETE_ATTACHMENT:
      return "GL_FRAMEBUFFER_INCOMPLETE_ATTACHMENT";
    case GL_FRAMEBUFFER_INCOMPLETE_MISSING_ATTACHMENT:
      return "GL_FRAMEBUFFER_INCOMPLETE_MISSING_ATTACHMENT";
    case GL_FRAMEBUFFER_UNSUPPORTED:
      return "GL_FRAMEBUFFER_UNSUPPORTED";
    case GL_FRAMEBUFFER_INCOMPLETE_MULTISAMPLE:
      return "GL_FRAMEBUFFER_INCOMPLETE_MULTISAMPLE";
    default:
      return "GL framebuffer status " + std::to_string(status);
  }
}

void CheckFramebuffer(const char* name) {
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  if (status != GL_FRAMEBUFFER_COMPLETE) {
    throw std::runtime_error(std::string("glCheckFramebufferStatus(") + name +
                             ") failed: " + FramebufferStatusName(status));
  }
}

// (re)allocates `mat` as a continuous rows x cols image of `type` unless it already is one
void EnsureImage(cv::Mat* mat, int rows, int cols, int type) {
  if (!mat->isContinuous()) mat->release();
  mat->create(rows, cols, type);
}

void ValidateCamera(const CameraModel& camera) {
  if (camera.width <= 0 || camera.height <= 0) {
    throw std::runtime_error("CameraModel: size " + std::to_string(camera.width) + "x" +
                             std::to_string(camera.height) + " is not positive");
  }
  if (!(camera.fx > 0) || !(camera.fy > 0) || !std::isfinite(camera.fx) ||
      !std::isfinite(camera.fy) || !std::isfinite(camera.cx) || !std::isfinite(camera.cy)) {
    throw std::runtime_error("CameraModel: focal lengths fx=" + std::to_string(camera.fx) +
                             ", fy=" + std::to_string(camera.fy) +
                             " must be positive and cx, cy finite");
  }
  if (!(camera.near_mm > 0) || !(camera.far_mm > camera.near_mm) || !std::isfinite(camera.far_mm)) {
    throw std::runtime_error("CameraModel: near_mm=" + std::to_string(camera.near_mm) +
                             ", far_mm=" + std::to_string(camera.far_mm) +
                             " must satisfy 0 < near_mm < far_mm");
  }
}

// true when the mesh is a union of closed surfaces wound counter-clockwise seen from outside:
// with vertices welded by position, every edge is used as often in one direction as in the other,
// and every connected piece encloses a positive volume. Back faces of such a mesh never show.
bool IsClosedAndOutward(const TriangleMesh& mesh) {
  // weld vertices at identical positions (+0 and -0 alike)
  struct PositionHash {
    size_t operator()(const std::array<uint32_t, 3>& key) const {
      return (static_cast<size_t>(key[0]) * 73856093u) ^ (static_cast<size_t>(key[1]) * 19349663u) ^
             (static_cast<size_t>(key[2]) * 83492791u);
    }
  };
  std::unordered_map<std::array<uint32_t, 3>, uint32_t, PositionHash> welded_ids;
  std::vector<uint32_t> welded(mesh.positions_mm.size());
  for (size_t i = 0; i < mesh.positions_mm.size(); ++i) {
    std::array<uint32_t, 3> key;
    for (int c = 0; c < 3; ++c) {
      const float value = mesh.positions_mm[i][c] + 0.f;
      std::memcpy(&key[c], &value, sizeof(value));
    }
    welded[i] = welded_ids.emplace(key, static_cast<uint32_t>(welded_ids.size())).first->second;
  }

  // edges used equally in both directions; pieces joined by shared vertices
  std::unordered_map<uint64_t, int> edge_balance;
  std::vector<uint32_t> parent(welded_ids.size());
  std::iota(parent.begin(), parent.end(), 0u);
  const auto find = [&parent](uint32_t v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  for (const auto& triangle : mesh.triangles) {
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = welded[triangle[e]];
      const uint32_t b = welded[triangle[(e + 1) % 3]];
      if (a == b) continue;
      const uint64_t key = (static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b);
      edge_balance[key] += a < b ? 1 : -1;
      parent[find(a)] = find(b);
    }
  }
  for (const auto& [edge, balance] : edge_balance) {
    if (balance != 0) return false;
  }

  // signed volume of each piece (divergence theorem), positive when wound outwards
  std::unordered_map<uint32_t, double> volume_x6;
  for (const auto& triangle : mesh.triangles) {
    const Eigen::Vector3d p0 = mesh.positions_mm[triangle[0]].cast<double>();
    const Eigen::Vector3d p1 = mesh.positions_mm[triangle[1]].cast<double>();
    const Eigen::Vector3d p2 = mesh.positions_mm[triangle[2]].cast<double>();
    volume_x6[find(welded[triangle[0]])] += p0.dot(p1.cross(p2));
  }
  for (const auto& [piece, volume] : volume_x6) {
    if (!(volume > 0)) return false;
  }
  return true;
}

// The axis-aligned box around `box`'s eight corners moved by `target_from_source`.
Eigen::AlignedBox3d TransformedBox(const Eigen::Isometry3d& target_from_source,
                                   const Eigen::AlignedBox3d& box) {
  Eigen::AlignedBox3d out;
  for (int k = 0; k < 8; ++k) {
    out.extend(target_from_source * box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(k)));
  }
  return out;
}

// A right-handed rotation light_from_world whose z axis (third row) is `forward`, unit.
Eigen::Matrix3d LightFromWorldRotation(const Eigen::Vector3d& forward) {
  const Eigen::Vector3d helper =
      std::abs(forward.z()) < 0.9 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x = helper.cross(forward).normalized();
  const Eigen::Vector3d y = forward.cross(x);
  Eigen::Matrix3d light_from_world;
  light_from_world.row(0) = x;
  light_from_world.row(1) = y;
  light_from_world.row(2) = forward;
  return light_from_world;
}

// How one light sees the scene for its shadow map.
struct ShadowView {
  Eigen::Matrix4d clip_from_world;  // GL clip coordinates of the light's depth pass
  double depth_bias = 0;            // kShadowDepthBiasMm in map depth units (at the box centre)
  double normal_offset_mm = 0;      // kShadowNormalOffsetTexels in mm (at the far side)
};

// The view of `light` covering `box` (world, mm) with a map of `size` texels per side:
// orthographic along a directional light, a perspective from a point light aimed at the box
// centre. The light frame is right-handed with z forward and clip x, y growing with light x, y,
// like the camera's, so triangles keep their winding (front faces stay front faces).
ShadowView MakeShadowView(const Light& light, const Eigen::AlignedBox3d& box, int size) {
  // a margin of 2 texels keeps the filter taps of the box's edges on the map
  const double margin = 1 + 4.0 / size;
  ShadowView view;
  Eigen::Matrix4d clip_from_light = Eigen::Matrix4d::Zero();
  Eigen::Isometry3d light_from_world = Eigen::Isometry3d::Identity();
  if (light.type == Light::Type::kDirectional) {
    // the box in a frame looking along the light, around its centre
    light_from_world.linear() =
        LightFromWorldRotation(light.direction_world.cast<double>().normalized());
    light_from_world.translation() = -(light_from_world.linear() * box.center());
    const Eigen::AlignedBox3d bounds = TransformedBox(light_from_world, box);
    const Eigen::Vector3d half = (bounds.sizes() / 2).cwiseMax(1e-3);
    const double half_x = half.x() * margin;
    const double half_y = half.y() * margin;
    const double near = bounds.min().z() - 0.01 * half.z() - 1;
    const double far = bounds.max().z() + 0.01 * half.z() + 1;
    const Eigen::Vector3d center = bounds.center();
    clip_from_light(0, 0) = 1 / half_x;
    clip_from_light(0, 3) = -center.x() / half_x;
    clip_from_light(1, 1) = 1 / half_y;
    clip_from_light(1, 3) = -center.y() / half_y;
    clip_from_light(2, 2) = 2 / (far - near);
    clip_from_light(2, 3) = -(far + near) / (far - near);
    clip_from_light(3, 3) = 1;
    view.depth_bias = kShadowDepthBiasMm / (far - near);
    view.normal_offset_mm = kShadowNormalOffsetTexels * 2 * std::max(half_x, half_y) / size;
  } else {
    // the box seen from the light, aimed at its centre
    const Eigen::Vector3d position = light.position_world.cast<double>();
    Eigen::Vector3d aim = box.center() - position;
    const double distance = aim.norm();
    aim = distance > 1e-9 ? Eigen::Vector3d(aim / distance) : Eigen::Vector3d(0, 0, -1);
    light_from_world.linear() = LightFromWorldRotation(aim);
    light_from_world.translation() = -(light_from_world.linear() * position);
    const Eigen::AlignedBox3d bounds = TransformedBox(light_from_world, box);
    // near and far planes; a light inside the box gets a small near plane
    const double far = bounds.max().z() * 1.01 + 1;
    const double near = std::max(bounds.min().z() * 0.99, far * 1e-3);
    // the cone: every corner in front of the near plane, up to the largest half angle
    const double max_tan = std::tan(kMaxShadowHalfAngleRad);
    double tan_x = 1e-6;
    double tan_y = 1e-6;
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3d q =
          light_from_world * box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(k));
      const double z = std::max(q.z(), near);
      tan_x = std::max(tan_x, std::abs(q.x()) / z);
      tan_y = std::max(tan_y, std::abs(q.y()) / z);
    }
    tan_x = std::min(tan_x * margin, max_tan);
    tan_y = std::min(tan_y * margin, max_tan);
    clip_from_light(0, 0) = 1 / tan_x;
    clip_from_light(1, 1) = 1 / tan_y;
    clip_from_light(2, 2) = (far + near) / (far - near);
    clip_from_light(2, 3) = -2 * far * near / (far - near);
    clip_from_light(3, 2) = 1;
    // map depth 0.5 (a + b / z) + 0.5 changes by far near / ((far - near) z^2) per mm
    const double z_center = std::clamp(distance, near, far);
    view.depth_bias = kShadowDepthBiasMm * far * near / ((far - near) * z_center * z_center);
    view.normal_offset_mm = kShadowNormalOffsetTexels * 2 * far * std::max(tan_x, tan_y) / size;
  }
  view.clip_from_world = clip_from_light * light_from_world.matrix();
  return view;
}

// an sRGB display value (0..1) in linear light
float SrgbToLinear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

// the GGX roughness whose lobe is as wide as a Blinn-Phong lobe of this exponent: Beckmann's
// alpha^2 = 2 / (n + 2), roughness = sqrt(alpha)
float RoughnessOfShininess(float shininess) {
  return std::pow(2.f / (std::max(shininess, 0.f) + 2.f), 0.25f);
}

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
                  std::vector<std::vector<std::pair<int, cv::Vec3f>>>* edges) {
  const cv::Mat& colors = *colors_in_out;
  const int rows = colors.rows;
  const int cols = colors.cols;
  edges->resize(rows);
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
    for (int v = range.start; v < range.end; ++v) {
      std::vector<std::pair<int, cv::Vec3f>>& row_edges = (*edges)[v];
      row_edges.clear();
      const uint16_t* own_row = surfaces.ptr<uint16_t>(v);
      const cv::Vec<uint16_t, 4>* sample_row = sample_surfaces.ptr<cv::Vec<uint16_t, 4>>(v);
      for (int u = 0; u < cols; ++u) {
        const uint16_t own = own_row[u];
        const cv::Vec<uint16_t, 4>& ids = sample_row[u];
        bool edge = false;
        for (int k = 0; k < samples; ++k) edge = edge || ids[k] != own;
        if (!edge) continue;
        const cv::Vec3f own_color = colors.at<cv::Vec3f>(v, u);
        cv::Vec3f sum(0, 0, 0);
        for (int k = 0; k < samples; ++k) {
          cv::Vec3f color = own_color;
          if (ids[k] != own) {
            const int dx = positions[2 * k] < 0.5f ? -1 : 1;
            const int dy = positions[2 * k + 1] < 0.5f ? -1 : 1;
            const int offsets[8][2] = {{dx, 0},  {0, dy},   {dx, dy},  {-dx, 0},
                                       {0, -dy}, {-dx, dy}, {dx, -dy}, {-dx, -dy}};
            for (const auto& offset : offsets) {
              const int qu = std::clamp(u + offset[0], 0, cols - 1);
              const int qv = std::clamp(v + offset[1], 0, rows - 1);
              if (surfaces.at<uint16_t>(qv, qu) == ids[k]) {
                color = colors.at<cv::Vec3f>(qv, qu);
                break;
              }
            }
          }
          sum += color;
        }
        row_edges.emplace_back(u, sum * (1.f / static_cast<float>(samples)));
      }
    }
  });
  for (int v = 0; v < rows; ++v) {
    cv::Vec3f* row = colors_in_out->ptr<cv::Vec3f>(v);
    for (const auto& [u, color] : (*edges)[v]) row[u] = color;
  }
}

}  // namespace

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

  void Find(GLuint program) {
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
  float environment_intensity = 0;
  float light_irradiance[Renderer::kMaxLights][3] = {};  // physically based: pi x diffuse
  float light_vectors[Renderer::kMaxLights][4] = {};     // see scene.vert.glsl
  float light_terms[Renderer::kMaxLights][3] = {};
  float shadow_from_camera[Renderer::kMaxLights][16] = {};  // column-major
  float shadow_normal_offset_mm[Renderer::kMaxLights] = {};
  float shadow_depth_bias[Renderer::kMaxLights] = {};
  float shadow_texel = 0;
};

void LightUniforms::Set(const FrameUniforms& f) const {
  const GLsizei n = f.light_count;
  if (n > 0) glUniform4fv(light_vector_camera, n, &f.light_vectors[0][0]);
  if (f.shadows) {
    glUniformMatrix4fv(shadow_from_camera, n, GL_FALSE, &f.shadow_from_camera[0][0]);
    glUniform1fv(shadow_normal_offset_mm, n, f.shadow_normal_offset_mm);
    glUniform1fv(shadow_depth_bias, n, f.shadow_depth_bias);
    glUniform1f(shadow_texel, f.shadow_texel);
  }
}

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
  int shadow_map_size = 0;
  int shadow_map_layers = 0;

  // physically based frames: the programs, the DFG table, the environments;
  // a single-sampled framebuffer shading each pixel once (colour, id, camera z, surface), and
  // when anti-aliased a multisampled coverage pass and its resolve (resolve.frag.glsl)
  std::array<PbrProgram, (kMaxLights + 1) * 16> pbr;
  GLuint empty_vertex_array = 0;  // 0 until the first physically based frame
  GLuint dfg_texture = 0;
  std::vector<EnvironmentTexture> environments;
  GLuint shaded_framebuffer = 0;  // colour, instance, camera z, surface; the scene depth buffer
  GLuint shaded_texture = 0;      // RGBA16F linear colour
  GLuint surface_texture = 0;     // R16UI item index + 1
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

  // per Render call
  uint64_t frame = 0;
  const CameraModel* frame_camera = nullptr;
  FrameUniforms frame_uniforms;
  GLuint bound_texture = 0;  // on kMaterialTextureUnit
  std::array<ShadowView, kMaxLights> shadow_views;

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
  PbrProgram& Pbr(int light_count, bool shadows, bool textured, bool environment, bool detailed);
  PbrProgram& UsePbr(bool textured, bool detailed);
  void EnsurePbrResources();
  void EnsurePbrTargets(int samples);
  GLuint ResolveProgram(int samples);
  void DrawPbrSurface(const DrawItem& item, size_t index,
                      const Eigen::Isometry3d& camera_from_world, const MeshBuffers& mesh,
                      const Material& material, GLsizei first, GLsizei count);
  void ReadLinearColor(cv::Mat* color);
  void CompositeBackground(const RenderOptions& options, RenderResult* result);
  void RenderPbr(const CameraModel& camera, const RenderOptions& options,
                 const std::vector<DrawItem>& items, RenderResult* result);
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
  Eigen::AlignedBox3d WorldBounds(const std::vector<DrawItem>& items) const;
  void EnsureShadowMaps(int size, int layers);
  void RenderShadowMaps(const std::vector<Light>& lights, int size,
                        const std::vector<DrawItem>& items);
};

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

ShadingProgram& Renderer::Impl::Shading(int light_count, bool shadows, bool textured) {
  ShadingProgram& shading_program = shading[ProgramIndex(light_count, shadows, textured)];
  if (shading_program.program != 0) return shading_program;
  const std::string header =
      "#version 330 core\n#define LIGHT_COUNT " + std::to_string(light_count) +
      "\n#define SHADOWS " + (shadows ? "1" : "0") + "\n#define TEXTURED " +
      (textured ? "1" : "0") + "\n#define ENVIRONMENT 0\n#define SHADOW_TAPS 4\n";
  const std::string name = "scene program, " + std::to_string(light_count) + " lights" +
                           (shadows ? ", shadows" : "") + (textured ? ", texture" : "");
  const GLuint program = LinkProgram(header + projection_glsl + scene_vert_glsl,
                                     header + shadow_lookup_glsl + phong_frag_glsl, name.c_str());
  shading_program.projection.Find(program);
  shading_program.instance_id = glGetUniformLocation(program, "instance_id");
  shading_program.material_color_linear = glGetUniformLocation(program, "material_color_linear");
  shading_program.material_specular = glGetUniformLocation(program, "material_specular");
  shading_program.material_shininess = glGetUniformLocation(program, "material_shininess");
  shading_program.lights.Find(program);
  shading_program.light_terms = glGetUniformLocation(program, "light_terms");
  // samplers on their fixed units
  glUseProgram(program);
  glUniform1i(glGetUniformLocation(program, "material_texture"), kMaterialTextureUnit);
  glUniform1i(glGetUniformLocation(program, "shadow_maps"), kShadowMapUnit);
  CheckGlError(name.c_str());
  shading_program.program = program;
  return shading_program;
}

ShadingProgram& Renderer::Impl::UseShading(bool textured) {
  const FrameUniforms& f = frame_uniforms;
  ShadingProgram& s = Shading(f.light_count, f.shadows, textured);
  glUseProgram(s.program);
  if (s.frame == frame) return s;

  // first use this frame: camera, lights and shadow maps
  s.frame = frame;
  s.item = nullptr;
  SetProjection(s.projection, *frame_camera);
  s.lights.Set(f);
  if (f.light_count > 0) glUniform3fv(s.light_terms, f.light_count, &f.light_terms[0][0]);
  return s;
}

PbrProgram& Renderer::Impl::Pbr(int light_count, bool shadows, bool textured, bool environment,
                                bool detailed) {
  PbrProgram& p = pbr[light_count * 16 + (shadows ? 8 : 0) + (textured ? 4 : 0) +
                      (detailed ? 2 : 0) + (environment ? 1 : 0)];
  if (p.program != 0) return p;
  const std::string header =
      "#version 330 core\n#define LIGHT_COUNT " + std::to_string(light_count) +
      "\n#define SHADOWS " + (shadows ? "1" : "0") + "\n#define TEXTURED " +
      (textured ? "1" : "0") + "\n#define ENVIRONMENT " + (environment ? "1" : "0") +
      "\n#define DETAIL " + (detailed ? "1" : "0") + "\n#define SHADOW_TAPS 1\n";
  const std::string name = "physically based program, " + std::to_string(light_count) + " lights" +
                           (shadows ? ", shadows" : "") + (textured ? ", texture" : "") +
                           (environment ? ", environment" : "") + (detailed ? ", detail" : "");
  const GLuint program = LinkProgram(
      header + projection_glsl + scene_vert_glsl,
      header + color_glsl + brdf_glsl + shadow_lookup_glsl + pbr_frag_glsl, name.c_str());
  p.projection.Find(program);
  const auto find = [program](const char* uniform) {
    return glGetUniformLocation(program, uniform);
  };
  p.base_color_linear = find("base_color_linear");
  p.metallic = find("metallic");
  p.roughness = find("roughness");
  p.dielectric_f0 = find("dielectric_f0");
  p.lights.Find(program);
  p.light_irradiance = find("light_irradiance");
  p.environment_from_camera = find("environment_from_camera");
  p.environment_max_lod = find("environment_max_lod");
  p.irradiance_sh = find("irradiance_sh");
  p.environment_intensity = find("environment_intensity");
  p.instance_id = find("instance_id");
  p.surface_id = find("surface_id");
  p.detail_frame = find("detail_frame");
  p.detail_kind = find("detail_kind");
  p.detail_strength = find("detail_strength");
  // samplers on their fixed units
  glUseProgram(program);
  glUniform1i(find("material_texture"), kMaterialTextureUnit);
  glUniform1i(find("shadow_maps"), kShadowMapUnit);
  glUniform1i(find("dfg_lut"), kDfgUnit);
  glUniform1i(find("environment_radiance"), kEnvironmentUnit);
  CheckGlError(name.c_str());
  p.program = program;
  return p;
}

PbrProgram& Renderer::Impl::UsePbr(bool textured, bool detailed) {
  const FrameUniforms& f = frame_uniforms;
  PbrProgram& p = Pbr(f.light_count, f.shadows, textured, f.environment != nullptr, detailed);
  glUseProgram(p.program);
  if (p.frame == frame) return p;

  // first use this frame: camera, lights, shadow maps and environment
  p.frame = frame;
  p.item = nullptr;
  SetProjection(p.projection, *frame_camera);
  p.lights.Set(f);
  if (f.light_count > 0) {
    glUniform3fv(p.light_irradiance, f.light_count, &f.light_irradiance[0][0]);
  }
  if (f.environment != nullptr) {
    glUniformMatrix3fv(p.environment_from_camera, 1, GL_FALSE, f.environment_from_camera);
    glUniform1f(p.environment_max_lod, PrefilteredEnvironment::kLevels - 1);
    glUniform3fv(p.irradiance_sh, 9, f.environment->irradiance_sh[0].data());
    glUniform1f(p.environment_intensity, f.environment_intensity);
  }
  return p;
}

void Renderer::Impl::EnsurePbrResources() {
  if (empty_vertex_array != 0) return;
  // the resolve pass draws one triangle without vertex data
  glGenVertexArrays(1, &empty_vertex_array);

  // the coverage pass: the surface each sample sees
  const std::string header =
      "#version 330 core\n#define LIGHT_COUNT 0\n#define SHADOWS 0\n#define TEXTURED 0\n"
      "#define ENVIRONMENT 0\n";
  coverage_program = LinkProgram(header + projection_glsl + scene_vert_glsl,
                                 header + coverage_frag_glsl, "coverage program");
  coverage_projection.Find(coverage_program);
  coverage_surface_id = glGetUniformLocation(coverage_program, "surface_id");

  // the DFG table, (n.v, roughness) -> (Fresnel peak part, albedo for f0 = 1)
  const cv::Mat dfg = ComputeDfgLut(kDfgSize, 512);
  glGenTextures(1, &dfg_texture);
  glActiveTexture(GL_TEXTURE0 + kDfgUnit);
  glBindTexture(GL_TEXTURE_2D, dfg_texture);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RG32F, kDfgSize, kDfgSize, 0, GL_RG, GL_FLOAT, dfg.data);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  bound_texture = 0;

  glGenFramebuffers(1, &shaded_framebuffer);
  glGenFramebuffers(1, &coverage_framebuffer);
  glGenFramebuffers(1, &resolve_framebuffer);
  glGenTextures(1, &shaded_texture);
  glGenTextures(1, &surface_texture);
  glGenTextures(1, &coverage_texture);
  glGenRenderbuffers(1, &coverage_depth_buffer);
  glGenRenderbuffers(1, &resolve_buffer);
  CheckGlError("Renderer: physically based set-up");
}

void Renderer::Impl::EnsurePbrTargets(int samples) {
  const GLenum draw_buffers[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2,
                                 GL_COLOR_ATTACHMENT3};
  const auto plain_texture = [](GLuint texture, GLenum format, int w, int h) {
    glBindTexture(GL_TEXTURE_2D, texture);
    glTexImage2D(GL_TEXTURE_2D, 0, format, w, h, 0, format == GL_R16UI ? GL_RED_INTEGER : GL_RGBA,
                 format == GL_R16UI ? GL_UNSIGNED_SHORT : GL_FLOAT, nullptr);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, 0);
  };
  if (width != pbr_width || height != pbr_height) {
    // shaded once per pixel: colour and surface of its own, id, camera z and depth shared with
    // the Phong framebuffer
    glActiveTexture(GL_TEXTURE0 + kSetupUnit);
    plain_texture(shaded_texture, GL_RGBA16F, width, height);
    plain_texture(surface_texture, GL_R16UI, width, height);
    glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
    glBindRenderbuffer(GL_RENDERBUFFER, resolve_buffer);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA16UI, width, height);
    CheckGlError("Renderer: physically based framebuffer storage");
    glBindFramebuffer(GL_FRAMEBUFFER, shaded_framebuffer);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, shaded_texture, 0);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_RENDERBUFFER,
                              instance_buffer);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT2, GL_RENDERBUFFER,
                              camera_z_buffer);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT3, GL_TEXTURE_2D, surface_texture, 0);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_buffer);
    glDrawBuffers(4, draw_buffers);
    CheckFramebuffer("physically based framebuffer");
    glBindFramebuffer(GL_FRAMEBUFFER, resolve_framebuffer);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER,
                              resolve_buffer);
    glDrawBuffers(1, draw_buffers);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    CheckFramebuffer("resolve framebuffer");
    pbr_width = width;
    pbr_height = height;
    coverage_samples = 0;
  }
  if (samples <= 1 || samples == coverage_samples) return;

  // the coverage targets: the surface of each sample, and the samples' depth
  glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, coverage_texture);
  glTexImage2DMultisample(GL_TEXTURE_2D_MULTISAMPLE, samples, GL_R16UI, width, height, GL_TRUE);
  glBindRenderbuffer(GL_RENDERBUFFER, coverage_depth_buffer);
  glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_DEPTH_COMPONENT32F, width, height);
  CheckGlError("Renderer: coverage framebuffer storage");
  glBindFramebuffer(GL_FRAMEBUFFER, coverage_framebuffer);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE,
                         coverage_texture, 0);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER,
                            coverage_depth_buffer);
  glDrawBuffers(1, draw_buffers);
  CheckFramebuffer("coverage framebuffer");
  coverage_samples = samples;
}

GLuint Renderer::Impl::ResolveProgram(int samples) {
  if (resolve_programs[samples] != 0) return resolve_programs[samples];
  const std::string name = "resolve program, " + std::to_string(samples) + " samples";
  const GLuint program = LinkProgram(
      fullscreen_vert_glsl,
      "#version 330 core\n#define SAMPLES " + std::to_string(samples) + "\n" + resolve_frag_glsl,
      name.c_str());
  glUseProgram(program);
  glUniform1i(glGetUniformLocation(program, "coverage"), kResolveCoverageUnit);
  CheckGlError(name.c_str());
  resolve_programs[samples] = program;
  return program;
}

void Renderer::Impl::DrawPbrSurface(const DrawItem& item, size_t index,
                                    const Eigen::Isometry3d& camera_from_world,
                                    const MeshBuffers& mesh, const Material& material,
                                    GLsizei first, GLsizei count) {
  const bool textured = material.texture_id >= 0;
  const SurfaceDetail& detail = item.detail;
  const bool detailed = detail.kind != SurfaceDetail::Kind::kNone && detail.strength > 0;
  PbrProgram& p = UsePbr(textured, detailed);
  if (p.item != &item) {
    SetCameraFromObject(p.projection, camera_from_world, item);
    glUniform1ui(p.instance_id, item.instance_id);
    glUniform1ui(p.surface_id, static_cast<GLuint>(index + 1));
    if (detailed) {
      glUniform4f(p.detail_frame, detail.offset.x(), detail.offset.y(), detail.offset.z(),
                  1.f / detail.scale_mm);
      glUniform1i(p.detail_kind, static_cast<int>(detail.kind));
      glUniform1f(p.detail_strength, detail.strength);
    }
    p.item = &item;
  }

  // the material with the item's gain: what a mesh material leaves open, the item's gives
  const float metallic = material.metallic >= 0 ? material.metallic : item.material.metallic;
  const float metal = std::clamp(metallic + item.gain.metallic, 0.f, 1.f);
  // the base colour: the surface's colour where it is a dielectric, its metal colour where it is
  // metal, blended by metallic, in linear light
  const Eigen::Vector3f color =
      material.color.cwiseProduct(item.gain.color).cwiseMax(0.f).cwiseMin(1.f);
  const Eigen::Vector3f metal_color =
      (material.metal_color.minCoeff() >= 0 ? material.metal_color : material.color)
          .cwiseProduct(item.gain.color)
          .cwiseMax(0.f)
          .cwiseMin(1.f);
  Eigen::Vector3f base;
  for (int c = 0; c < 3; ++c) {
    base[c] = (1 - metal) * SrgbToLinear(color[c]) + metal * SrgbToLinear(metal_color[c]);
  }
  const float roughness = material.roughness >= 0        ? material.roughness
                          : item.material.roughness >= 0 ? item.material.roughness
                                                         : RoughnessOfShininess(material.shininess);
  glUniform3fv(p.base_color_linear, 1, base.data());
  glUniform1f(p.metallic, metal);
  glUniform1f(p.roughness, std::clamp(roughness * item.gain.roughness, 0.f, 1.f));
  glUniform1f(p.dielectric_f0,
              std::clamp(0.08f * material.specular * item.gain.specular, 0.f, 1.f));
  if (textured && textures[material.texture_id] != bound_texture) {
    bound_texture = textures[material.texture_id];
    glBindTexture(GL_TEXTURE_2D, bound_texture);
  }
  Draw(mesh, first, count);
}

void Renderer::Impl::ReadLinearColor(cv::Mat* color) {
  // half floats as they are stored (a plain copy), widened here: far faster than asking the GL
  // for RGB floats
  EnsureImage(&half_colors, height, width, CV_16FC4);
  glReadPixels(0, 0, width, height, GL_RGBA, GL_HALF_FLOAT, half_colors.data);
  half_colors.convertTo(float_colors, CV_32F);
  EnsureImage(color, height, width, CV_32FC3);
  cv::cvtColor(float_colors, *color, cv::COLOR_RGBA2RGB);
}

void Renderer::Impl::CompositeBackground(const RenderOptions& options, RenderResult* result) {
  // the background image, decoded and scaled, where nothing was drawn (camera z 0); before the
  // edges are resolved, which blend it with what borders it. A table lookup per pixel left
  // costs less than uploading the image and drawing it (on llvmpipe, 3-7 % of a frame)
  if (options.background_image.empty()) return;
  float linear[256];
  for (int k = 0; k < 256; ++k) {
    linear[k] = options.background_scale * SrgbToLinear(static_cast<float>(k) / 255.f);
  }
  for (int v = 0; v < height; ++v) {
    const float* depth = result->depth_mm.ptr<float>(v);
    const uint8_t* background = options.background_image.ptr<uint8_t>(v);
    float* color = result->color_linear.ptr<float>(v);
    for (int u = 0; u < width; ++u) {
      if (depth[u] != 0.f) continue;
      for (int c = 0; c < 3; ++c) color[3 * u + c] = linear[background[3 * u + c]];
    }
  }
}

void Renderer::Impl::RenderPbr(const CameraModel& camera, const RenderOptions& options,
                               const std::vector<DrawItem>& items, RenderResult* result) {
  EnsurePbrResources();
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();
  Resize(camera.width, camera.height);
  const int samples = options.msaa_samples;
  EnsurePbrTargets(samples);
  glDisable(GL_COLOR_LOGIC_OP);
  glEnable(GL_DEPTH_TEST);

  // each pixel shaded at its centre: clear, the items near first, the background image; ids and
  // camera z of the same surface as its colour
  glBindFramebuffer(GL_FRAMEBUFFER, shaded_framebuffer);
  glViewport(0, 0, width, height);
  GLfloat background[4] = {0, 0, 0, 1};
  for (int c = 0; c < 3; ++c) {
    background[c] = options.background_scale * SrgbToLinear(options.background_rgb[c]);
  }
  const GLuint zero_id[4] = {0, 0, 0, 0};
  const GLfloat zero_z[4] = {0, 0, 0, 0};
  const GLfloat far_depth = 1;
  glClearBufferfv(GL_COLOR, 0, background);
  glClearBufferuiv(GL_COLOR, 1, zero_id);
  glClearBufferfv(GL_COLOR, 2, zero_z);
  glClearBufferuiv(GL_COLOR, 3, zero_id);
  glClearBufferfv(GL_DEPTH, 0, &far_depth);
  for (const auto& [z, index] : draw_order) {
    const DrawItem& item = items[index];
    const MeshBuffers& mesh = meshes[item.mesh_id];
    if (!item.use_mesh_materials || mesh.materials.empty()) {
      DrawPbrSurface(item, index, camera_from_world, mesh, item.material, 0, mesh.index_count);
      continue;
    }
    for (size_t k = 0; k < mesh.range_firsts.size(); ++k) {
      DrawPbrSurface(item, index, camera_from_world, mesh, mesh.materials[mesh.range_materials[k]],
                     mesh.range_firsts[k], mesh.range_counts[k]);
    }
  }
  EnsureImage(&result->instance, height, width, CV_16UC1);
  EnsureImage(&result->depth_mm, height, width, CV_32FC1);
  EnsureImage(&result->color_linear, height, width, CV_32FC3);
  glReadBuffer(GL_COLOR_ATTACHMENT1);
  glReadPixels(0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_SHORT, result->instance.data);
  glReadBuffer(GL_COLOR_ATTACHMENT2);
  glReadPixels(0, 0, width, height, GL_RED, GL_FLOAT, result->depth_mm.data);
  if (samples <= 1) {
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    ReadLinearColor(&result->color_linear);
    CompositeBackground(options, result);
  } else {
    // the surface each sample sees: a cheap multisampled pass
    glBindFramebuffer(GL_FRAMEBUFFER, coverage_framebuffer);
    glClearBufferuiv(GL_COLOR, 0, zero_id);
    glClearBufferfv(GL_DEPTH, 0, &far_depth);
    glUseProgram(coverage_program);
    SetProjection(coverage_projection, camera);
    for (const auto& [z, index] : draw_order) {
      const DrawItem& item = items[index];
      SetCameraFromObject(coverage_projection, camera_from_world, item);
      glUniform1ui(coverage_surface_id, static_cast<GLuint>(index + 1));
      Draw(meshes[item.mesh_id]);
    }

    // the samples' surfaces, four to a texel, read back with the centres' colours and surfaces
    GLfloat positions[2 * 4] = {};
    for (int k = 0; k < samples; ++k) glGetMultisamplefv(GL_SAMPLE_POSITION, k, positions + 2 * k);
    glBindFramebuffer(GL_FRAMEBUFFER, resolve_framebuffer);
    glDisable(GL_DEPTH_TEST);
    if (culling) {
      glDisable(GL_CULL_FACE);
      culling = false;
    }
    glUseProgram(ResolveProgram(samples));
    glActiveTexture(GL_TEXTURE0 + kResolveCoverageUnit);
    glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, coverage_texture);
    glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
    glBindVertexArray(empty_vertex_array);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glEnable(GL_DEPTH_TEST);
    EnsureImage(&sample_surfaces, height, width, CV_16UC4);
    EnsureImage(&centre_surfaces, height, width, CV_16UC1);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glReadPixels(0, 0, width, height, GL_RGBA_INTEGER, GL_UNSIGNED_SHORT, sample_surfaces.data);
    glBindFramebuffer(GL_FRAMEBUFFER, shaded_framebuffer);
    glReadBuffer(GL_COLOR_ATTACHMENT3);
    glReadPixels(0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_SHORT, centre_surfaces.data);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    ReadLinearColor(&result->color_linear);
    CompositeBackground(options, result);
    ResolveEdges(centre_surfaces, sample_surfaces, samples, positions, &result->color_linear,
                 &edge_colors);
  }
  glBindVertexArray(0);
  result->color.release();
  CheckGlError("Renderer::Render (physically based)");
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

int Renderer::AddMesh(const TriangleMesh& mesh) {
  static_assert(sizeof(std::array<uint32_t, 3>) == 3 * sizeof(uint32_t), "packed triangles");
  // check the mesh
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

  // interleave position, normal and texture coordinate
  std::vector<float> vertices;
  vertices.reserve(vertex_count * 8);
  for (size_t i = 0; i < vertex_count; ++i) {
    vertices.insert(vertices.end(), mesh.positions_mm[i].data(), mesh.positions_mm[i].data() + 3);
    vertices.insert(vertices.end(), mesh.normals[i].data(), mesh.normals[i].data() + 3);
    const Eigen::Vector2f uv = mesh.uvs.empty() ? Eigen::Vector2f::Zero() : mesh.uvs[i];
    vertices.insert(vertices.end(), uv.data(), uv.data() + 2);
  }

  // triangles grouped by material, in their order within each group
  MeshBuffers buffers;
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
      buffers.range_firsts.push_back(first);
      buffers.range_counts.push_back(count);
      buffers.range_materials.push_back(static_cast<int>(m));
    }
  }

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

void Renderer::Render(const CameraModel& camera, const std::vector<Light>& lights,
                      const RenderOptions& options, const std::vector<DrawItem>& items,
                      RenderResult* result) {
  Impl& impl = *impl_;
  impl.context.MakeCurrent();
  impl.Validate(camera, items);
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
  if (options.shadows && (options.shadow_map_size < kMinShadowMapSize ||
                          options.shadow_map_size > kMaxShadowMapSize)) {
    throw std::runtime_error("Renderer::Render: shadow_map_size " +
                             std::to_string(options.shadow_map_size) + " is outside " +
                             std::to_string(kMinShadowMapSize) + ".." +
                             std::to_string(kMaxShadowMapSize));
  }
  const bool pbr = options.shading == Shading::kPbr;
  if (pbr) {
    const int samples = options.msaa_samples;
    const int max_samples = MaxMsaaSamples();
    if ((samples != 1 && samples != 2 && samples != 4) || samples > max_samples) {
      throw std::runtime_error("Renderer::Render: msaa_samples " + std::to_string(samples) +
                               " is not 1, 2 or 4 up to " + std::to_string(max_samples) +
                               ", the most this GL takes (" + Description() + ")");
    }
    if (options.environment_id < -1 ||
        options.environment_id >= static_cast<int>(impl.environments.size())) {
      throw std::runtime_error("Renderer::Render: unknown environment_id " +
                               std::to_string(options.environment_id) + " (" +
                               std::to_string(impl.environments.size()) + " environments added)");
    }
    if (!(options.environment_intensity >= 0) || !std::isfinite(options.environment_intensity) ||
        !(options.background_scale >= 0) || !std::isfinite(options.background_scale) ||
        !std::isfinite(options.environment_yaw_deg)) {
      throw std::runtime_error("Renderer::Render: environment_intensity " +
                               std::to_string(options.environment_intensity) +
                               " and background_scale " + std::to_string(options.background_scale) +
                               " must be finite and >= 0, environment_yaw_deg finite");
    }
  } else if (options.shading != Shading::kPhong) {
    throw std::runtime_error("Renderer::Render: unknown shading");
  }
  for (size_t i = 0; i < items.size(); ++i) {
    const MeshBuffers& mesh = impl.meshes[items[i].mesh_id];
    if (!items[i].use_mesh_materials || mesh.materials.empty()) {
      impl.ValidateMaterial(items[i].material, mesh,
                            "Renderer::Render: item " + std::to_string(i) + "'s material");
    }
  }
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();

  // lights in the camera frame: towards a directional light, the position of a point light
  FrameUniforms& frame = impl.frame_uniforms;
  frame.light_count = static_cast<int>(lights.size());
  frame.shadows = options.shadows && !lights.empty() &&
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
      frame.light_irradiance[i][c] = static_cast<float>(M_PI) * light.diffuse;
  }

  // shadow maps, from each light over the box of all items
  if (frame.shadows) {
    impl.RenderShadowMaps(lights, options.shadow_map_size, items);
    // from the camera frame to (s, t, depth) in [0, 1] of each map
    Eigen::Matrix4d texture_from_clip = 0.5 * Eigen::Matrix4d::Identity();
    texture_from_clip.topRightCorner<3, 1>().setConstant(0.5);
    texture_from_clip(3, 3) = 1;
    for (size_t i = 0; i < lights.size(); ++i) {
      const ShadowView& view = impl.shadow_views[i];
      const Eigen::Matrix4f shadow_from_camera =
          (texture_from_clip * view.clip_from_world * camera.world_from_camera.matrix())
              .cast<float>();
      std::memcpy(frame.shadow_from_camera[i], shadow_from_camera.data(),
                  sizeof(frame.shadow_from_camera[i]));
      frame.shadow_normal_offset_mm[i] = static_cast<float>(view.normal_offset_mm);
      frame.shadow_depth_bias[i] = static_cast<float>(view.depth_bias);
    }
    frame.shadow_texel = 1.f / static_cast<float>(options.shadow_map_size);
    glActiveTexture(GL_TEXTURE0 + kShadowMapUnit);
    glBindTexture(GL_TEXTURE_2D_ARRAY, impl.shadow_maps);
    glActiveTexture(GL_TEXTURE0 + kMaterialTextureUnit);
  }

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
    frame.environment =
        options.environment_id >= 0 ? &impl.environments[options.environment_id] : nullptr;
    frame.environment_intensity = options.environment_intensity;
    const Eigen::Matrix3f environment_from_camera =
        (Eigen::AngleAxisd(-options.environment_yaw_deg * M_PI / 180, Eigen::Vector3d::UnitZ())
             .toRotationMatrix() *
         camera.world_from_camera.linear())
            .cast<float>();
    std::memcpy(frame.environment_from_camera, environment_from_camera.data(),
                sizeof(frame.environment_from_camera));
    impl.RenderPbr(camera, options, items, result);
    return;
  }

  // clear: background colour, id 0, camera z 0, far depth
  impl.Resize(camera.width, camera.height);
  glBindFramebuffer(GL_FRAMEBUFFER, impl.scene_framebuffer);
  glViewport(0, 0, impl.width, impl.height);
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
  for (const auto& [z, index] : impl.draw_order) {
    const DrawItem& item = items[index];
    const MeshBuffers& mesh = impl.meshes[item.mesh_id];
    if (!item.use_mesh_materials || mesh.materials.empty()) {
      impl.DrawSurface(item, camera_from_world, mesh, item.material, 0, mesh.index_count);
      continue;
    }
    for (size_t k = 0; k < mesh.range_firsts.size(); ++k) {
      impl.DrawSurface(item, camera_from_world, mesh, mesh.materials[mesh.range_materials[k]],
                       mesh.range_firsts[k], mesh.range_counts[k]);
    }
  }
  glBindVertexArray(0);

  // read back; framebuffer row 0 is image row 0 already (see projection.glsl)
  EnsureImage(&result->color, impl.height, impl.width, CV_8UC3);
  EnsureImage(&result->depth_mm, impl.height, impl.width, CV_32FC1);
  EnsureImage(&result->instance, impl.height, impl.width, CV_16UC1);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  glReadPixels(0, 0, impl.width, impl.height, GL_RGB, GL_UNSIGNED_BYTE, result->color.data);
  glReadBuffer(GL_COLOR_ATTACHMENT1);
  glReadPixels(0, 0, impl.width, impl.height, GL_RED_INTEGER, GL_UNSIGNED_SHORT,
               result->instance.data);
  glReadBuffer(GL_COLOR_ATTACHMENT2);
  glReadPixels(0, 0, impl.width, impl.height, GL_RED, GL_FLOAT, result->depth_mm.data);
  result->color_linear.release();
  CheckGlError("Renderer::Render");

  // the background image where nothing was drawn (camera z 0), copied exactly
  if (!options.background_image.empty()) {
    for (int v = 0; v < impl.height; ++v) {
      const float* depth = result->depth_mm.ptr<float>(v);
      const uint8_t* background_row = options.background_image.ptr<uint8_t>(v);
      uint8_t* color = result->color.ptr<uint8_t>(v);
      for (int u = 0; u < impl.width; ++u) {
        if (depth[u] == 0.f) std::memcpy(color + 3 * u, background_row + 3 * u, 3);
      }
    }
  }
}

std::vector<cv::Mat> Renderer::RenderSilhouettes(const CameraModel& camera,
                                                 const std::vector<DrawItem>& items) {
  std::vector<cv::Mat> masks;
  RenderSilhouettes(camera, items, &masks);
  return masks;
}

void Renderer::RenderSilhouettes(const CameraModel& camera, const std::vector<DrawItem>& items,
                                 std::vector<cv::Mat>* masks, std::vector<cv::Mat>* beyond) {
  Impl& impl = *impl_;
  impl.context.MakeCurrent();
  impl.Validate(camera, items);

  // one empty mask per object
  impl.objects.clear();
  for (const DrawItem& item : items) {
    if (item.instance_id > 0) impl.objects.push_back(&item);
  }
  impl.Resize(camera.width, camera.height);
  masks->resize(impl.objects.size());
  impl.mask_data.resize(impl.objects.size());
  for (size_t k = 0; k < masks->size(); ++k) {
    cv::Mat& mask = (*masks)[k];
    EnsureImage(&mask, impl.height, impl.width, CV_8UC1);
    mask.setTo(0);
    impl.mask_data[k] = mask.data;
  }
  if (beyond != nullptr) beyond->assign(impl.objects.size(), cv::Mat());
  if (impl.objects.empty()) return;

  glBindFramebuffer(GL_FRAMEBUFFER, impl.silhouette_framebuffer);
  glViewport(0, 0, impl.width, impl.height);
  const size_t pixel_count = impl.bits.size();
  impl.DrawSilhouetteBits(camera, impl.objects, &impl.bits, [&](size_t first, size_t) {
    uint8_t* const* data = impl.mask_data.data() + first;
    for (size_t i = 0; i < pixel_count; ++i) {
      for (uint32_t word = impl.bits[i]; word != 0; word &= word - 1) {
        data[__builtin_ctz(word)][i] = 255;
      }
    }
  });
  if (beyond != nullptr) impl.RenderBeyond(camera, *masks, beyond);
  CheckGlError("Renderer::RenderSilhouettes");
}

// Draws `to_draw` into the bound R32UI framebuffer (its viewport set), up to 32 at a time, one
// bit each, with no depth test: each ORs its bit into every pixel it covers. After each group
// of `count` objects from `first` on, the bits are read back into `read_back` and `spread` is
// called.
void Renderer::Impl::DrawSilhouetteBits(const CameraModel& camera,
                                        const std::vector<const DrawItem*>& to_draw,
                                        std::vector<uint32_t>* read_back,
                                        const std::function<void(size_t, size_t)>& spread) {
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_COLOR_LOGIC_OP);
  glUseProgram(silhouette_program);
  SetProjection(silhouette_projection, camera);
  for (size_t first = 0; first < to_draw.size(); first += kObjectsPerSilhouettePass) {
    const size_t count = std::min<size_t>(kObjectsPerSilhouettePass, to_draw.size() - first);
    const GLuint zero[4] = {0, 0, 0, 0};
    glClearBufferuiv(GL_COLOR, 0, zero);
    for (size_t k = 0; k < count; ++k) {
      const DrawItem& item = *to_draw[first + k];
      SetCameraFromObject(silhouette_projection, camera_from_world, item);
      glUniform1ui(object_bit, 1u << k);
      Draw(meshes[item.mesh_id]);
    }
    glBindVertexArray(0);
    glReadPixels(0, 0, camera.width, camera.height, GL_RED_INTEGER, GL_UNSIGNED_INT,
                 read_back->data());
    spread(first, count);
  }
  glDisable(GL_COLOR_LOGIC_OP);
}

// The objects whose mask touches the image's edge or is empty, drawn again on the image with a
// margin around it (bop_toolkit's calc_gt_info renders 3 x 3 images with the image in the
// middle: the same here, as far as the GL allows), each into its own canvas mask.
void Renderer::Impl::RenderBeyond(const CameraModel& camera, const std::vector<cv::Mat>& masks,
                                  std::vector<cv::Mat>* beyond) {
  std::vector<const DrawItem*> cut;
  std::vector<size_t> index_of_cut;
  for (size_t k = 0; k < masks.size(); ++k) {
    const cv::Mat& mask = masks[k];
    const bool at_edge =
        cv::countNonZero(mask.row(0)) > 0 || cv::countNonZero(mask.row(mask.rows - 1)) > 0 ||
        cv::countNonZero(mask.col(0)) > 0 || cv::countNonZero(mask.col(mask.cols - 1)) > 0;
    if (at_edge || cv::countNonZero(mask) == 0) {
      cut.push_back(objects[k]);
      index_of_cut.push_back(k);
    }
  }
  if (cut.empty()) return;

  // the canvas: the image and a margin of its own size on each side, within the GL's limits
  GLint max_size = 0;
  glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &max_size);
  GLint max_viewport[2] = {0, 0};
  glGetIntegerv(GL_MAX_VIEWPORT_DIMS, max_viewport);
  const int margin_x =
      std::max(0, std::min(camera.width, (std::min(max_size, max_viewport[0]) - camera.width) / 2));
  const int margin_y = std::max(
      0, std::min(camera.height, (std::min(max_size, max_viewport[1]) - camera.height) / 2));
  CameraModel canvas = camera;
  canvas.width = camera.width + 2 * margin_x;
  canvas.height = camera.height + 2 * margin_y;
  canvas.cx = camera.cx + margin_x;
  canvas.cy = camera.cy + margin_y;
  if (margin_framebuffer == 0) {
    glGenRenderbuffers(1, &margin_buffer);
    glGenFramebuffers(1, &margin_framebuffer);
  }
  glBindFramebuffer(GL_FRAMEBUFFER, margin_framebuffer);
  if (canvas.width != margin_canvas_width || canvas.height != margin_canvas_height) {
    glBindRenderbuffer(GL_RENDERBUFFER, margin_buffer);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_R32UI, canvas.width, canvas.height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, margin_buffer);
    const GLenum draw_buffers[] = {GL_COLOR_ATTACHMENT0};
    glDrawBuffers(1, draw_buffers);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    CheckFramebuffer("silhouette margin framebuffer");
    margin_canvas_width = canvas.width;
    margin_canvas_height = canvas.height;
    margin_bits.resize(static_cast<size_t>(canvas.width) * canvas.height);
  }
  glViewport(0, 0, canvas.width, canvas.height);
  DrawSilhouetteBits(canvas, cut, &margin_bits, [&](size_t first, size_t count) {
    for (size_t k = 0; k < count; ++k) {
      cv::Mat& out = (*beyond)[index_of_cut[first + k]];
      out = cv::Mat::zeros(canvas.height, canvas.width, CV_8UC1);
      const uint32_t bit = 1u << k;
      for (size_t i = 0; i < margin_bits.size(); ++i) {
        if ((margin_bits[i] & bit) != 0) out.data[i] = 255;
      }
      // the image itself: its pixels are the exact pass's
      out(cv::Rect(margin_x, margin_y, camera.width, camera.height)).setTo(0);
    }
  });
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
