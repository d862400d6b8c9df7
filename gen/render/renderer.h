#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "gen/mesh/mesh.h"
#include "gen/render/camera.h"
#include "gen/render/environment.h"
#include "gen/render/lights.h"

namespace stackgen {

/// A pinhole camera in the OpenCV convention: its intrinsics (Intrinsics: pixel centres at
/// integer coordinates, so a point at (x, y, z) in the camera frame lands in pixel
/// (round(fx x / z + cx), round(fy y / z + cy))), its pose and its clipping range.
struct CameraModel : Intrinsics {
  /// OpenCV camera frame: x right, y down (row 0 at the top), z forward; millimetres.
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  double near_mm = 10;    // surfaces closer than this (camera z) are clipped
  double far_mm = 10000;  // surfaces farther than this (camera z) are clipped
};

/// Surface appearance. Colours are display values in [0, 1]. Phong shading runs in linear colour
/// with gamma 2 (linear = display^2), so a surface lit at full strength shows `color` itself;
/// physically based shading decodes them as sRGB into the base colour.
struct Material {
  Eigen::Vector3f color{0.7f, 0.7f, 0.7f};
  /// Phong: strength of the white highlight, >= 0 (configs allow 0..2). Physically based: the
  /// reflectance of a non-metal at normal incidence is 0.08 x specular (Blender's "specular";
  /// 0.5 gives 4 %, most plastics and paints).
  float specular = 0.5f;
  float shininess = 32.f;  // Blinn-Phong exponent
  /// A texture from Renderer::AddTexture, or -1 for none. Its texel colour (display values)
  /// multiplies `color`; the mesh needs texture coordinates (TriangleMesh::uvs).
  int texture_id = -1;
  /// Physically based shading only. Metallic 0..1 (0 a dielectric, 1 a bare metal whose
  /// reflectance is its colour); a negative value in a mesh's own material means "not stated
  /// by the file": the DrawItem's material gives it.
  float metallic = 0.f;
  /// Perceptual roughness 0..1 (alpha = roughness^2), clamped below at 0.03; negative: derived
  /// from shininess as (2 / (shininess + 2))^(1/4), the GGX lobe as wide as the Blinn-Phong one
  /// (40 -> 0.47). In a mesh's own material, negative means the DrawItem's material gives it.
  float roughness = -1.f;
  /// Physically based only: the colour where the surface is metal (display values), blended
  /// with `color` by metallic; negative: `color` (MeshMaterial::metal_color).
  Eigen::Vector3f metal_color{-1.f, -1.f, -1.f};
};

/// Procedural surface detail of physically based shading (pbr.frag.glsl): roughness and
/// brightness that vary with the position in the item's own frame (value noise).
struct SurfaceDetail {
  enum class Kind {
    kNone,
    kCast,     // mottled roughness and brightness, as cast metal
    kBrushed,  // fine streaks along the object's x axis
    kScuffed,  // dust patches (lighter, rougher) and scuff marks
    kMoulded,  // scuffed, and injection-moulding marks: ejector-pin rings, flow lines
    kWood,     // growth rings across y and grain along x, darkening the colour
  };
  Kind kind = Kind::kNone;
  float strength = 0.5f;            // 0..1
  float scale_mm = 2.f;             // the features' size, > 0
  Eigen::Vector3f offset{0, 0, 0};  // shifts the pattern, in features: a new one per scene
};

/// One mesh placed in the scene.
struct DrawItem {
  int mesh_id = 0;                                                      // from Renderer::AddMesh
  Eigen::Isometry3d world_from_object = Eigen::Isometry3d::Identity();  // millimetres
  uint16_t instance_id = 0;  // 0 = not an object (bin, background props)
  /// Used for the whole mesh when it has no materials of its own, or use_mesh_materials is false.
  Material material;
  /// true: a mesh with materials (AddMesh kept them) draws each triangle with its own material.
  bool use_mesh_materials = true;
  MaterialGain gain;     // applied to the material used (the mesh's or `material`)
  SurfaceDetail detail;  // physically based shading only
  /// false: drawn, but not into the shadow maps, and not counted in the bounds they cover (a
  /// large floor under everything would spread their texels thin); it still receives shadows.
  bool casts_shadow = true;
};

/// How colour is computed.
enum class Shading {
  /// The paper's: Blinn-Phong per light, display values with gamma 2 in RenderResult::color.
  kPhong,
  /// Metallic-roughness GGX microfacets lit by the lights and an environment, anti-aliased,
  /// linear radiance in RenderResult::color_linear (the camera response comes later).
  kPbr,
};

/// How a frame is drawn beyond the camera, lights and items.
struct RenderOptions {
  Shading shading = Shading::kPhong;
  /// Display RGB in [0, 1] where nothing is drawn (unless background_image is set).
  Eigen::Vector3f background_rgb{0, 0, 0};
  /// Empty, or CV_8UC3 RGB of exactly camera width x height: shown unchanged (no shading) where
  /// nothing is drawn, instead of background_rgb.
  cv::Mat background_image;
  /// Shadow mapping, one depth map per light covering the bounding box of all items
  /// (orthographic along a directional light; a perspective from a point light aimed at the box
  /// centre, at most 80 degrees off that aim: surfaces outside are lit): a surface in the shadow
  /// of a light gets only that light's ambient term, edges filtered over 3 x 3 texels. Default
  /// off. Costs about one depth-only pass per light plus four filtered lookups per light and
  /// fragment.
  bool shadows = false;
  /// Texels per side of each shadow map, 256..8192 (default 2048).
  int shadow_map_size = 2048;

  // physically based shading only:
  /// An environment from Renderer::AddEnvironment lighting every surface, or -1 for none.
  int environment_id = -1;
  /// The environment turned about the world's z axis (counter-clockwise seen from above), deg.
  double environment_yaw_deg = 0;
  /// Multiplies the environment's radiance, >= 0.
  float environment_intensity = 1.f;
  /// The environment's colour: multiplies its linear RGB radiance per channel, each >= 0
  /// (a black body's colour of luminance 1 tints it; white leaves it as it is).
  Eigen::Vector3f environment_color{1, 1, 1};
  /// Samples per pixel of the colour image's edges: 1 (off), 2 or 4, at most
  /// MaxMsaaSamples(). Each pixel is shaded once at its centre and a multisampled coverage pass
  /// blends edge pixels (subpixel reconstruction, Chajdas et al. 2011; see renderer.cc). Depth, ids
  /// and silhouettes never depend on it: they come from the single-sampled pass, exact at centres.
  int msaa_samples = 4;
  /// Linear radiance of a background pixel whose display value is 1 (background_rgb and
  /// background_image are decoded as sRGB and scaled by this), >= 0.
  float background_scale = 1.f;
  /// Physically based shading only: also compute, per pixel, how much of a 3D camera's
  /// projected pattern comes back to this camera (RenderResult::projector_return) from a
  /// projector (or the active stereo pair's second view) at `projector_position_mm`, world frame.
  bool projector_return = false;
  Eigen::Vector3d projector_position_mm{0, 0, 0};
  /// Physically based shading with an environment only: > 0 lets what lies within this many
  /// millimetres of a surface hide the environment's light from it (EnvironmentVisibility, from
  /// the depth image: the floor at the foot of a tote's walls and between parts gets less of
  /// it, as in a path tracer); the lights' own shadows are their shadow maps'. 0 (default): the
  /// environment lights every surface whole. Finite and >= 0.
  float environment_occlusion_mm = 0.f;
};

/// The images of one render, all camera.width x camera.height, row 0 at the top.
struct RenderResult {
  cv::Mat color;  // CV_8UC3, RGB order (not BGR); Phong shading only (empty otherwise)
  /// CV_32FC3 linear RGB radiance (1 = what a white matte surface under a light of strength 1
  /// reflects); physically based shading only (empty otherwise).
  cv::Mat color_linear;
  cv::Mat depth_mm;  // CV_32FC1, z of the surface in the camera frame, mm; 0 where nothing drawn
  cv::Mat instance;  // CV_16UC1, instance_id of the nearest surface, 0 = background or non-object
  /// CV_32FC1, with RenderOptions::projector_return only (empty otherwise): the radiance this
  /// camera receives from the projector's light reflected by the surface of the pixel's centre,
  /// relative to a white matte surface facing the projector (pi x BRDF x cos, averaged over
  /// R, G and B, from the same material, normal and detail as the colour): about 1 for white
  /// paper, 0 for a mirror whose reflection misses the camera, far above 1 in a metal's
  /// highlight; 0 where nothing is drawn or the surface faces away from the projector. The
  /// projector's shadow is not in it (see gen/randomize/depth_sensor.h).
  cv::Mat projector_return;
};

/// Renders scenes of meshes headless with OpenGL 3.3 core through EGL (see EglContext): colour,
/// depth and instance id, plus per-object silhouettes, all three in one single-sampled pass, so
/// every pixel's colour, depth and id come from the same surface; physically based frames then
/// smooth the colour of edge pixels with a multisampled coverage pass (anti-aliased edges, exact
/// labels). Surfaces take the materials and
/// textures of their model file or of their DrawItem; shadows (optional) come from one
/// depth-only pass per light into its own map before the scene pass.
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

  /// Uploads an RGB8 texture (CV_8UC3, RGB, row 0 = top of the image) with mipmaps, sampled
  /// linearly and repeated outside [0, 1]; returns its texture_id (0, 1, 2, ...). Throws
  /// std::runtime_error for an empty image, another type, a size over GL_MAX_TEXTURE_SIZE, or a
  /// GL error.
  int AddTexture(const cv::Mat& rgb);

  /// Uploads a mesh (millimetres, object frame) once, with its texture coordinates and, when
  /// mesh.materials is non-empty, its materials and their textures (one texture per textured
  /// material); returns its mesh_id (0, 1, 2, ...). A mesh made of closed surfaces wound
  /// counter-clockwise seen from outside (checked here, vertices welded by position) is drawn
  /// with back faces culled, about twice as fast on llvmpipe; any other mesh (open, inside out)
  /// is drawn two-sided. Throws std::runtime_error if the mesh has no triangles, normals or uvs
  /// (when not empty) and positions differ in count, an index is out of range, triangle_material
  /// does not match triangles and materials, or a material has a texture that is not CV_8UC3 or
  /// that the mesh has no texture coordinates for.
  int AddMesh(const TriangleMesh& mesh);

  /// Uploads a prefiltered environment (its levels as the mip chain of one equirectangular
  /// texture, its irradiance harmonics) once; returns its environment_id (0, 1, 2, ...). Throws
  /// std::runtime_error when it does not have PrefilteredEnvironment::kLevels levels, each half
  /// the previous one, 2:1 and CV_32FC3, or for a GL error.
  int AddEnvironment(const PrefilteredEnvironment& environment);

  /// Renders the items over the background of `options`, with shadows when options.shadows:
  /// Blinn-Phong (per light: ambient + diffuse + specular; a point light's direction is taken
  /// per fragment) into `color`, or physically based (options.shading kPbr; see pbr.frag.glsl)
  /// into `color_linear`. A triangle's material is its mesh material when
  /// item.use_mesh_materials and the mesh has materials, item.material otherwise, with item.gain
  /// applied; materials, lights, shadows, the environment and multisampling change colours only,
  /// never which pixels are covered, their depth or ids. The framebuffers follow camera.width and
  /// camera.height (re-allocated only when they change). At most kMaxLights lights; the shader
  /// for each number of lights, with or without shadows, texture and environment, is compiled
  /// on its first use. Throws std::runtime_error for an unknown mesh_id, texture_id or
  /// environment_id, a texture on a mesh without texture coordinates, a bad camera (size, focal
  /// length, near/far), too many or invalid lights, a background image of the wrong size or
  /// type, a shadow_map_size, msaa_samples, environment_intensity or background_scale out of
  /// range, or a GL error (by name).
  RenderResult Render(const CameraModel& camera, const std::vector<Light>& lights,
                      const RenderOptions& options, const std::vector<DrawItem>& items);

  /// As above, writing into `result`; its images are reused when they already have the right
  /// size and type, so a loop that passes the same result allocates nothing.
  void Render(const CameraModel& camera, const std::vector<Light>& lights,
              const RenderOptions& options, const std::vector<DrawItem>& items,
              RenderResult* result);

  /// Pixels each item with instance_id > 0 would cover drawn alone (no occluders), same camera
  /// and rasterisation as Render: binary masks CV_8UC1 (255 inside), in the order of the items
  /// with instance_id > 0. For an unoccluded object the mask equals its pixels in Render's
  /// instance map exactly. Used for px_count_all and the amodal box and mask. Throws as Render.
  std::vector<cv::Mat> RenderSilhouettes(const CameraModel& camera,
                                         const std::vector<DrawItem>& items);

  /// As above, writing into `masks` (resized to the number of objects); masks already of the
  /// right size are reused. With `beyond` (resized to the number of objects), also what each
  /// object covers outside the image, as bop_toolkit's calc_gt_info counts it: an object whose
  /// mask touches the image's edge, or is empty, is drawn again on a canvas that holds the image
  /// and a margin of the image's width and height on each side (3 x 3 images, the image at
  /// (width, height); less where GL_MAX_RENDERBUFFER_SIZE is smaller), and its `beyond` mask is
  /// that canvas, CV_8UC1 255 inside, zero over the image itself (whose pixels are in `masks`,
  /// exact). Every other object gets an empty Mat.
  void RenderSilhouettes(const CameraModel& camera, const std::vector<DrawItem>& items,
                         std::vector<cv::Mat>* masks, std::vector<cv::Mat>* beyond = nullptr);

  /// The platform, GL_RENDERER and GL_VERSION of the context (see EglContext::Description).
  std::string Description() const;

  /// The most RenderOptions::msaa_samples this GL takes (llvmpipe: 4).
  int MaxMsaaSamples() const;

  /// Most lights one Render takes.
  static constexpr int kMaxLights = 8;
  /// Smallest and largest RenderOptions::shadow_map_size.
  static constexpr int kMinShadowMapSize = 256;
  static constexpr int kMaxShadowMapSize = 8192;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
