#include "gen/render/renderer_internal.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <stdexcept>
#include <utility>

#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace render_internal {

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
    view.near_mm = near;
    view.far_mm = far;
    view.half_width = std::max(half_x, half_y);
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
    view.perspective = true;
    view.near_mm = near;
    view.far_mm = far;
    view.half_width = std::max(tan_x, tan_y);
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

}  // namespace render_internal

void LightUniforms::Set(const FrameUniforms& f) const {
  const GLsizei n = f.light_count;
  if (n > 0) glUniform4fv(light_vector_camera, n, &f.light_vectors[0][0]);
  if (f.shadows) {
    glUniformMatrix4fv(shadow_from_camera, n, GL_FALSE, &f.shadow_from_camera[0][0]);
    glUniform1fv(shadow_normal_offset_mm, n, f.shadow_normal_offset_mm);
    glUniform1fv(shadow_depth_bias, n, f.shadow_depth_bias);
    glUniform1f(shadow_texel, f.shadow_texel);
    if (f.soft_shadows) glUniform4fv(shadow_softness, n, &f.shadow_softness[0][0]);
  }
}

}  // namespace stackgen
