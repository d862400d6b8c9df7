#include "gen/render/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numeric>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include "gen/render/egl_context.h"

namespace stackgen {
namespace {

// both programs compute gl_Position with the same code and `invariant`, so a silhouette covers
// exactly the pixels the object covers in the scene pass. The projection is the exact pinhole
// model with image row v in framebuffer row v (row 0 first in memory, at the top of the image):
//   x_clip = 2 fx / w x + ((2 cx + 1) / w - 1) z,  y_clip = 2 fy / h y + ((2 cy + 1) / h - 1) z,
//   z_clip = a z + b (near -> -1, far -> 1),      w_clip = z.
constexpr char kProjectionGlsl[] = R"glsl(
uniform mat4 camera_from_object;  // mm
uniform vec4 projection;          // (2 fx / w, (2 cx + 1) / w - 1, 2 fy / h, (2 cy + 1) / h - 1)
uniform vec2 depth_coefficients;  // (a, b): z_clip = a z + b
invariant gl_Position;

vec4 ClipFromCamera(vec3 p) {
  return vec4(projection.x * p.x + projection.y * p.z, projection.z * p.y + projection.w * p.z,
              depth_coefficients.x * p.z + depth_coefficients.y, p.z);
}
)glsl";

constexpr char kSceneVertexGlsl[] = R"glsl(
layout(location = 0) in vec3 position_object;
layout(location = 1) in vec3 normal_object;
out vec3 position_camera;
out vec3 normal_camera;

void main() {
  vec4 p = camera_from_object * vec4(position_object, 1.0);
  position_camera = p.xyz;
  normal_camera = mat3(camera_from_object) * normal_object;
  gl_Position = ClipFromCamera(p.xyz);
}
)glsl";

// LIGHT_COUNT is defined per program: a loop with a constant count unrolls, a uniform count
// makes llvmpipe about twice as slow
constexpr char kSceneFragmentGlsl[] = R"glsl(
in vec3 position_camera;
in vec3 normal_camera;
layout(location = 0) out vec4 color_out;
layout(location = 1) out uint instance_out;
layout(location = 2) out float depth_out;
uniform uint instance_id;
uniform vec3 material_color_linear;
uniform float material_specular;
uniform float material_shininess;
#if LIGHT_COUNT > 0
uniform vec3 light_to_light_camera[LIGHT_COUNT];  // unit, towards the light
uniform vec3 light_terms[LIGHT_COUNT];            // (ambient, diffuse, specular)
#endif

void main() {
  // shade both sides: the back of a two-sided (open) mesh uses the flipped normal
  vec3 n = normalize(gl_FrontFacing ? normal_camera : -normal_camera);
  vec3 v = normalize(-position_camera);

  // blinn-phong per light, in linear colour
  vec3 linear = vec3(0.0);
  for (int i = 0; i < LIGHT_COUNT; ++i) {
    vec3 l = light_to_light_camera[i];
    float n_dot_l = max(dot(n, l), 0.0);
    float highlight = 0.0;
    if (n_dot_l > 0.0) highlight = pow(max(dot(n, normalize(l + v)), 0.0), material_shininess);
    linear += (light_terms[i].x + light_terms[i].y * n_dot_l) * material_color_linear +
              vec3(light_terms[i].z * material_specular * highlight);
  }

  // gamma 2 to display values (sqrt is far cheaper than pow on llvmpipe); id and camera z of
  // the same surface
  color_out = vec4(sqrt(clamp(linear, 0.0, 1.0)), 1.0);
  instance_out = instance_id;
  depth_out = position_camera.z;
}
)glsl";

constexpr char kSilhouetteVertexGlsl[] = R"glsl(
layout(location = 0) in vec3 position_object;

void main() {
  vec4 p = camera_from_object * vec4(position_object, 1.0);
  gl_Position = ClipFromCamera(p.xyz);
}
)glsl";

constexpr char kSilhouetteFragmentGlsl[] = R"glsl(#version 330 core
layout(location = 0) out uint bits_out;
uniform uint object_bit;  // ORed into the target by glLogicOp(GL_OR)

void main() { bits_out = object_bit; }
)glsl";

constexpr int kObjectsPerSilhouettePass = 32;  // one bit each in an R32UI target

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

}  // namespace

// one uploaded mesh
struct MeshBuffers {
  GLuint vertex_array = 0;
  GLuint vertex_buffer = 0;  // interleaved position (mm) and normal, 6 floats per vertex
  GLuint index_buffer = 0;
  GLsizei index_count = 0;
  bool cull_back_faces = false;  // closed and wound outwards (IsClosedAndOutward)
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

// the scene program for one number of lights
struct ShadingProgram {
  GLuint program = 0;  // 0 until first used
  ProjectionUniforms projection;
  GLint instance_id = -1;
  GLint material_color_linear = -1;
  GLint material_specular = -1;
  GLint material_shininess = -1;
  GLint light_to_light_camera = -1;
  GLint light_terms = -1;
};

struct Renderer::Impl {
  EglContext context;  // first member: destroyed last, taking every GL object with it
  std::vector<MeshBuffers> meshes;

  std::array<ShadingProgram, kMaxLights + 1> shading;  // by number of lights
  GLuint silhouette_program = 0;
  ProjectionUniforms silhouette_projection;
  GLint object_bit = -1;

  // scene framebuffer: colour RGBA8, instance R16UI, camera z R32F, depth buffer
  GLuint scene_framebuffer = 0;
  GLuint color_buffer = 0;
  GLuint instance_buffer = 0;
  GLuint camera_z_buffer = 0;
  GLuint depth_buffer = 0;
  // silhouette framebuffer: one bit per object, R32UI
  GLuint silhouette_framebuffer = 0;
  GLuint bits_buffer = 0;
  int width = 0;
  int height = 0;
  bool culling = false;  // GL_CULL_FACE state

  // reused between calls
  std::vector<std::pair<double, size_t>> draw_order;  // (camera z, item index), near first
  std::vector<uint32_t> bits;                         // silhouette read-back
  std::vector<const DrawItem*> objects;               // items with instance_id > 0
  std::vector<uint8_t*> mask_data;

  Impl(int width, int height);
  const ShadingProgram& Shading(int light_count);
  void Resize(int new_width, int new_height);
  void Validate(const CameraModel& camera, const std::vector<DrawItem>& items) const;
  void SetProjection(const ProjectionUniforms& uniforms, const CameraModel& camera) const;
  void SetCameraFromObject(const ProjectionUniforms& uniforms,
                           const Eigen::Isometry3d& camera_from_world, const DrawItem& item) const;
  void Draw(const MeshBuffers& mesh);
};

Renderer::Impl::Impl(int width, int height) {
  if (width <= 0 || height <= 0) {
    throw std::runtime_error("Renderer: size " + std::to_string(width) + "x" +
                             std::to_string(height) + " is not positive");
  }
  // the silhouette program; scene programs are built per number of lights when first used
  silhouette_program =
      LinkProgram(std::string("#version 330 core\n") + kProjectionGlsl + kSilhouetteVertexGlsl,
                  kSilhouetteFragmentGlsl, "silhouette program");
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

  // fixed state: tight rows on read-back, no blending; image rows run down the framebuffer, so a
  // triangle counter-clockwise seen from outside is clockwise in window coordinates
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glDisable(GL_BLEND);
  glDisable(GL_CULL_FACE);
  glFrontFace(GL_CW);
  glCullFace(GL_BACK);
  glDisable(GL_DITHER);
  glDepthFunc(GL_LESS);
  glLogicOp(GL_OR);
  CheckGlError("Renderer: set-up");
}

const ShadingProgram& Renderer::Impl::Shading(int light_count) {
  ShadingProgram& shading_program = shading[light_count];
  if (shading_program.program != 0) return shading_program;
  const std::string header =
      "#version 330 core\n#define LIGHT_COUNT " + std::to_string(light_count) + "\n";
  const std::string name = "scene program, " + std::to_string(light_count) + " lights";
  const GLuint program = LinkProgram(header + kProjectionGlsl + kSceneVertexGlsl,
                                     header + kSceneFragmentGlsl, name.c_str());
  shading_program.projection.Find(program);
  shading_program.instance_id = glGetUniformLocation(program, "instance_id");
  shading_program.material_color_linear = glGetUniformLocation(program, "material_color_linear");
  shading_program.material_specular = glGetUniformLocation(program, "material_specular");
  shading_program.material_shininess = glGetUniformLocation(program, "material_shininess");
  shading_program.light_to_light_camera = glGetUniformLocation(program, "light_to_light_camera");
  shading_program.light_terms = glGetUniformLocation(program, "light_terms");
  shading_program.program = program;
  return shading_program;
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

void Renderer::Impl::Draw(const MeshBuffers& mesh) {
  if (mesh.cull_back_faces != culling) {
    culling = mesh.cull_back_faces;
    if (culling) {
      glEnable(GL_CULL_FACE);
    } else {
      glDisable(GL_CULL_FACE);
    }
  }
  glBindVertexArray(mesh.vertex_array);
  glDrawElements(GL_TRIANGLES, mesh.index_count, GL_UNSIGNED_INT, nullptr);
}

Renderer::Renderer(int width, int height) : impl_(std::make_unique<Impl>(width, height)) {}

Renderer::~Renderer() = default;

int Renderer::AddMesh(const TriangleMesh& mesh) {
  static_assert(sizeof(std::array<uint32_t, 3>) == 3 * sizeof(uint32_t), "packed triangles");
  // check the mesh
  const size_t vertex_count = mesh.positions_mm.size();
  if (mesh.triangles.empty()) throw std::runtime_error("Renderer::AddMesh: mesh has no triangles");
  if (mesh.normals.size() != vertex_count) {
    throw std::runtime_error("Renderer::AddMesh: " + std::to_string(mesh.normals.size()) +
                             " normals for " + std::to_string(vertex_count) + " positions");
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

  // interleave position and normal
  std::vector<float> vertices;
  vertices.reserve(vertex_count * 6);
  for (size_t i = 0; i < vertex_count; ++i) {
    vertices.insert(vertices.end(), mesh.positions_mm[i].data(), mesh.positions_mm[i].data() + 3);
    vertices.insert(vertices.end(), mesh.normals[i].data(), mesh.normals[i].data() + 3);
  }

  // upload once into a vertex array of its own
  impl_->context.MakeCurrent();
  MeshBuffers buffers;
  glGenVertexArrays(1, &buffers.vertex_array);
  glGenBuffers(1, &buffers.vertex_buffer);
  glGenBuffers(1, &buffers.index_buffer);
  glBindVertexArray(buffers.vertex_array);
  glBindBuffer(GL_ARRAY_BUFFER, buffers.vertex_buffer);
  glBufferData(GL_ARRAY_BUFFER, vertices.size() * sizeof(float), vertices.data(), GL_STATIC_DRAW);
  glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, buffers.index_buffer);
  glBufferData(GL_ELEMENT_ARRAY_BUFFER, mesh.triangles.size() * sizeof(mesh.triangles[0]),
               mesh.triangles.data(), GL_STATIC_DRAW);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float),
                        reinterpret_cast<const void*>(3 * sizeof(float)));
  glBindVertexArray(0);
  buffers.index_count = static_cast<GLsizei>(mesh.triangles.size() * 3);
  buffers.cull_back_faces = IsClosedAndOutward(mesh);
  CheckGlError("Renderer::AddMesh");
  impl_->meshes.push_back(buffers);
  return static_cast<int>(impl_->meshes.size()) - 1;
}

RenderResult Renderer::Render(const CameraModel& camera, const std::vector<Light>& lights,
                              const Eigen::Vector3f& background_rgb,
                              const std::vector<DrawItem>& items) {
  RenderResult result;
  Render(camera, lights, background_rgb, items, &result);
  return result;
}

void Renderer::Render(const CameraModel& camera, const std::vector<Light>& lights,
                      const Eigen::Vector3f& background_rgb, const std::vector<DrawItem>& items,
                      RenderResult* result) {
  Impl& impl = *impl_;
  impl.context.MakeCurrent();
  impl.Validate(camera, items);
  if (lights.size() > static_cast<size_t>(kMaxLights)) {
    throw std::runtime_error("Renderer::Render: " + std::to_string(lights.size()) +
                             " lights, at most " + std::to_string(kMaxLights));
  }
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();

  // lights in the camera frame, pointing towards the light
  float to_light[kMaxLights][3] = {};
  float terms[kMaxLights][3] = {};
  for (size_t i = 0; i < lights.size(); ++i) {
    const Eigen::Vector3d direction_camera =
        camera_from_world.linear() * lights[i].direction_world.cast<double>();
    if (!(direction_camera.norm() > 0)) {
      throw std::runtime_error("Renderer::Render: light " + std::to_string(i) +
                               " has a zero or invalid direction_world");
    }
    const Eigen::Vector3f l = (-direction_camera.normalized()).cast<float>();
    std::memcpy(to_light[i], l.data(), sizeof(to_light[i]));
    terms[i][0] = lights[i].ambient;
    terms[i][1] = lights[i].diffuse;
    terms[i][2] = lights[i].specular;
  }

  // clear: background colour, id 0, camera z 0, far depth
  impl.Resize(camera.width, camera.height);
  glBindFramebuffer(GL_FRAMEBUFFER, impl.scene_framebuffer);
  glViewport(0, 0, impl.width, impl.height);
  glDisable(GL_COLOR_LOGIC_OP);
  glEnable(GL_DEPTH_TEST);
  const GLfloat background[4] = {background_rgb.x(), background_rgb.y(), background_rgb.z(), 1};
  const GLuint zero_id[4] = {0, 0, 0, 0};
  const GLfloat zero_z[4] = {0, 0, 0, 0};
  const GLfloat far_depth = 1;
  glClearBufferfv(GL_COLOR, 0, background);
  glClearBufferuiv(GL_COLOR, 1, zero_id);
  glClearBufferfv(GL_COLOR, 2, zero_z);
  glClearBufferfv(GL_DEPTH, 0, &far_depth);

  // per-frame uniforms
  const ShadingProgram& shading = impl.Shading(static_cast<int>(lights.size()));
  glUseProgram(shading.program);
  impl.SetProjection(shading.projection, camera);
  if (!lights.empty()) {
    glUniform3fv(shading.light_to_light_camera, static_cast<GLsizei>(lights.size()),
                 &to_light[0][0]);
    glUniform3fv(shading.light_terms, static_cast<GLsizei>(lights.size()), &terms[0][0]);
  }

  // draw near items first so the depth test rejects hidden fragments before shading
  impl.draw_order.clear();
  for (size_t i = 0; i < items.size(); ++i) {
    const double z = (camera_from_world * items[i].world_from_object.translation()).z();
    impl.draw_order.emplace_back(z, i);
  }
  std::sort(impl.draw_order.begin(), impl.draw_order.end());
  for (const auto& [z, index] : impl.draw_order) {
    const DrawItem& item = items[index];
    impl.SetCameraFromObject(shading.projection, camera_from_world, item);
    glUniform1ui(shading.instance_id, item.instance_id);
    // colours are display values: gamma 2 back to linear
    const Eigen::Vector3f color = item.material.color.cwiseMax(0.f).cwiseMin(1.f);
    const Eigen::Vector3f color_linear = color.cwiseProduct(color);
    glUniform3fv(shading.material_color_linear, 1, color_linear.data());
    glUniform1f(shading.material_specular, item.material.specular);
    glUniform1f(shading.material_shininess, item.material.shininess);
    impl.Draw(impl.meshes[item.mesh_id]);
  }
  glBindVertexArray(0);

  // read back; framebuffer row 0 is image row 0 already (see kProjectionGlsl)
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
  CheckGlError("Renderer::Render");
}

std::vector<cv::Mat> Renderer::RenderSilhouettes(const CameraModel& camera,
                                                 const std::vector<DrawItem>& items) {
  std::vector<cv::Mat> masks;
  RenderSilhouettes(camera, items, &masks);
  return masks;
}

void Renderer::RenderSilhouettes(const CameraModel& camera, const std::vector<DrawItem>& items,
                                 std::vector<cv::Mat>* masks) {
  Impl& impl = *impl_;
  impl.context.MakeCurrent();
  impl.Validate(camera, items);
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();

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
  if (impl.objects.empty()) return;

  // no depth test: each object ORs its bit into every pixel it covers
  glBindFramebuffer(GL_FRAMEBUFFER, impl.silhouette_framebuffer);
  glViewport(0, 0, impl.width, impl.height);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_COLOR_LOGIC_OP);
  glUseProgram(impl.silhouette_program);
  impl.SetProjection(impl.silhouette_projection, camera);
  const size_t pixel_count = impl.bits.size();
  for (size_t first = 0; first < impl.objects.size(); first += kObjectsPerSilhouettePass) {
    const size_t count = std::min<size_t>(kObjectsPerSilhouettePass, impl.objects.size() - first);
    // draw up to 32 objects, one bit each
    const GLuint zero[4] = {0, 0, 0, 0};
    glClearBufferuiv(GL_COLOR, 0, zero);
    for (size_t k = 0; k < count; ++k) {
      const DrawItem& item = *impl.objects[first + k];
      impl.SetCameraFromObject(impl.silhouette_projection, camera_from_world, item);
      glUniform1ui(impl.object_bit, 1u << k);
      impl.Draw(impl.meshes[item.mesh_id]);
    }
    glBindVertexArray(0);

    // read the bits back and spread them into the masks
    glReadPixels(0, 0, impl.width, impl.height, GL_RED_INTEGER, GL_UNSIGNED_INT, impl.bits.data());
    uint8_t* const* data = impl.mask_data.data() + first;
    for (size_t i = 0; i < pixel_count; ++i) {
      for (uint32_t word = impl.bits[i]; word != 0; word &= word - 1) {
        data[__builtin_ctz(word)][i] = 255;
      }
    }
  }
  glDisable(GL_COLOR_LOGIC_OP);
  CheckGlError("Renderer::RenderSilhouettes");
}

std::string Renderer::Description() const { return impl_->context.Description(); }

}  // namespace stackgen
