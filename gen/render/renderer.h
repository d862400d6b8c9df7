#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "gen/mesh/mesh.h"

namespace stackgen {

/// A pinhole camera in the OpenCV convention: pixel centres at integer coordinates, so a point
/// at (x, y, z) in the camera frame lands in pixel (round(fx x / z + cx), round(fy y / z + cy)).
struct CameraModel {
  int width = 640;                                    // pixels
  int height = 480;                                   // pixels
  double fx = 800, fy = 800, cx = 319.5, cy = 239.5;  // pixels
  /// OpenCV camera frame: x right, y down (row 0 at the top), z forward; millimetres.
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  double near_mm = 10;    // surfaces closer than this (camera z) are clipped
  double far_mm = 10000;  // surfaces farther than this (camera z) are clipped
};

/// Surface appearance. Colours are display values in [0, 1]; shading runs in linear colour with
/// gamma 2 (linear = display^2), so a surface lit at full strength shows `color` itself.
struct Material {
  Eigen::Vector3f color{0.7f, 0.7f, 0.7f};
  float specular = 0.5f;   // strength of the white highlight, [0, 1]
  float shininess = 32.f;  // Blinn-Phong exponent
};

/// A directional light with the paper's three OpenGL terms (ambient, diffuse, specular).
struct Light {
  Eigen::Vector3f direction_world{0, 0, -1};  // direction the light travels, unit, world frame
  float ambient = 0.25f, diffuse = 0.7f, specular = 0.4f;
};

/// One mesh placed in the scene.
struct DrawItem {
  int mesh_id = 0;                                                      // from Renderer::AddMesh
  Eigen::Isometry3d world_from_object = Eigen::Isometry3d::Identity();  // millimetres
  uint16_t instance_id = 0;  // 0 = not an object (bin, background props)
  Material material;
};

/// The images of one render, all camera.width x camera.height, row 0 at the top.
struct RenderResult {
  cv::Mat color;     // CV_8UC3, RGB order (not BGR)
  cv::Mat depth_mm;  // CV_32FC1, z of the surface in the camera frame, mm; 0 where nothing drawn
  cv::Mat instance;  // CV_16UC1, instance_id of the nearest surface, 0 = background or non-object
};

/// Renders scenes of meshes headless with OpenGL 3.3 core through EGL (see EglContext): colour,
/// depth and instance id in one pass, plus per-object silhouettes. No multisampling, so ids are
/// exact and every pixel's colour, depth and id come from the same surface.
///
/// Owns its own GL context; use a Renderer from one thread at a time (each call makes its
/// context current on the calling thread). Not copyable.
class Renderer {
 public:
  /// Creates the context and a width x height framebuffer (pixels). Throws std::runtime_error
  /// with the EGL/GL error name when the context or framebuffer cannot be made, or when a size
  /// is not positive.
  Renderer(int width, int height);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  /// Uploads a mesh (millimetres, object frame) once; returns its mesh_id (0, 1, 2, ...). A mesh
  /// made of closed surfaces wound counter-clockwise seen from outside (checked here, vertices
  /// welded by position) is drawn with back faces culled, about twice as fast on llvmpipe; any
  /// other mesh (open, inside out) is drawn two-sided. Throws std::runtime_error if the mesh has
  /// no triangles, normals and positions differ in count, or an index is out of range.
  int AddMesh(const TriangleMesh& mesh);

  /// Renders the items with Blinn-Phong shading (per light: ambient + diffuse + specular) over
  /// a plain background (display RGB in [0, 1]). The framebuffer follows camera.width and
  /// camera.height (re-allocated only when they change). At most kMaxLights lights; the shader
  /// for each number of lights is compiled on its first use. Throws
  /// std::runtime_error for an unknown mesh_id, a bad camera (size, focal length, near/far),
  /// too many lights, or a GL error (by name).
  RenderResult Render(const CameraModel& camera, const std::vector<Light>& lights,
                      const Eigen::Vector3f& background_rgb, const std::vector<DrawItem>& items);

  /// As above, writing into `result`; its images are reused when they already have the right
  /// size and type, so a loop that passes the same result allocates nothing.
  void Render(const CameraModel& camera, const std::vector<Light>& lights,
              const Eigen::Vector3f& background_rgb, const std::vector<DrawItem>& items,
              RenderResult* result);

  /// Pixels each item with instance_id > 0 would cover drawn alone (no occluders), same camera
  /// and rasterisation as Render: binary masks CV_8UC1 (255 inside), in the order of the items
  /// with instance_id > 0. For an unoccluded object the mask equals its pixels in Render's
  /// instance map exactly. Used for px_count_all and the amodal box and mask. Throws as Render.
  std::vector<cv::Mat> RenderSilhouettes(const CameraModel& camera,
                                         const std::vector<DrawItem>& items);

  /// As above, writing into `masks` (resized to the number of objects); masks already of the
  /// right size are reused.
  void RenderSilhouettes(const CameraModel& camera, const std::vector<DrawItem>& items,
                         std::vector<cv::Mat>* masks);

  /// The platform, GL_RENDERER and GL_VERSION of the context (see EglContext::Description).
  std::string Description() const;

  /// Most lights one Render takes.
  static constexpr int kMaxLights = 8;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
