// The physically based colour pass of Renderer: programs, targets, the environment light, the
// anti-aliased resolve and the background.
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

#include "gen/render/occlusion.h"
#include "shaders.h"

namespace stackgen {

// The shaders (gen/render/shaders/). Both the scene and the silhouette programs compute
// gl_Position with projection.glsl and `invariant`, so a silhouette covers exactly the pixels the
// object covers in the scene pass.
using namespace shaders;
using namespace render_internal;

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
                                bool detailed, bool projector, bool soft) {
  soft = soft && shadows;
  PbrProgram& p = pbr[(soft ? (kMaxLights + 1) * 32 : 0) + (projector ? (kMaxLights + 1) * 16 : 0) +
                      light_count * 16 + (shadows ? 8 : 0) + (textured ? 4 : 0) +
                      (detailed ? 2 : 0) + (environment ? 1 : 0)];
  if (p.program != 0) return p;
  const std::string header =
      "#version 330 core\n#define LIGHT_COUNT " + std::to_string(light_count) +
      "\n#define SHADOWS " + (shadows ? "1" : "0") + "\n#define TEXTURED " +
      (textured ? "1" : "0") + "\n#define ENVIRONMENT " + (environment ? "1" : "0") +
      "\n#define DETAIL " + (detailed ? "1" : "0") + "\n#define PROJECTOR " +
      (projector ? "1" : "0") + "\n#define SHADOW_TAPS " + (soft ? "0" : "1") + "\n";
  const std::string name = "physically based program, " + std::to_string(light_count) + " lights" +
                           (shadows ? ", shadows" : "") + (textured ? ", texture" : "") +
                           (environment ? ", environment" : "") + (detailed ? ", detail" : "") +
                           (projector ? ", projector" : "") + (soft ? ", soft shadows" : "");
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
  p.projector_camera = find("projector_camera");
  // samplers on their fixed units
  glUseProgram(program);
  glUniform1i(find("material_texture"), kMaterialTextureUnit);
  glUniform1i(find("shadow_maps"), kShadowMapUnit);
  if (soft) glUniform1i(find("shadow_depths"), kShadowDepthUnit);
  glUniform1i(find("dfg_lut"), kDfgUnit);
  glUniform1i(find("environment_radiance"), kEnvironmentUnit);
  CheckGlError(name.c_str());
  p.program = program;
  return p;
}

PbrProgram& Renderer::Impl::UsePbr(bool textured, bool detailed) {
  const FrameUniforms& f = frame_uniforms;
  PbrProgram& p = Pbr(f.light_count, f.shadows, textured, f.environment != nullptr, detailed,
                      f.projector, f.soft_shadows);
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
    glUniform3fv(p.environment_intensity, 1, f.environment_intensity);
  }
  if (f.projector) glUniform3fv(p.projector_camera, 1, f.projector_camera);
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
  glGenTextures(1, &return_texture);
  glGenTextures(1, &environment_texture);
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
    glTexImage2D(GL_TEXTURE_2D, 0, format, w, h, 0,
                 format == GL_R16UI ? GL_RED_INTEGER : (format == GL_R32F ? GL_RED : GL_RGBA),
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
    plain_texture(return_texture, GL_R32F, width, height);
    plain_texture(environment_texture, GL_RGBA16F, width, height);
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
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT4, GL_TEXTURE_2D, return_texture, 0);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT5, GL_TEXTURE_2D,
                           environment_texture, 0);
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

void Renderer::Impl::OccludeEnvironment(const CameraModel& camera, float radius_mm,
                                        RenderResult* result) {
  glReadBuffer(GL_COLOR_ATTACHMENT5);
  EnsureImage(&half_colors, height, width, CV_16FC4);
  glReadPixels(0, 0, width, height, GL_RGBA, GL_HALF_FLOAT, half_colors.data);
  half_colors.convertTo(float_colors, CV_32F);
  EnvironmentVisibility(result->depth_mm, camera, radius_mm, &environment_visibility);
  for (int v = 0; v < height; ++v) {
    const float* depth = result->depth_mm.ptr<float>(v);
    const float* open = environment_visibility.ptr<float>(v);
    const float* environment = float_colors.ptr<float>(v);
    float* color = result->color_linear.ptr<float>(v);
    for (int u = 0; u < width; ++u) {
      if (depth[u] == 0.f) continue;
      for (int c = 0; c < 3; ++c) color[3 * u + c] -= (1 - open[u]) * environment[4 * u + c];
    }
  }
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

void Renderer::Impl::ReadSampleSurfaces(const CameraModel& camera,
                                        const std::vector<DrawItem>& items, int samples,
                                        const Eigen::Isometry3d& camera_from_world,
                                        GLfloat* positions) {
  const GLuint zero_id[4] = {0, 0, 0, 0};
  const GLfloat far_depth = 1;
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
  // the projector's return is written only when asked for (the programs without it leave
  // location 4 alone), and the environment's share of the colour only when some of it is to be
  // hidden
  const bool projector = frame_uniforms.projector;
  const bool occlusion =
      options.environment_occlusion_mm > 0 && frame_uniforms.environment != nullptr;
  const GLenum draw_buffers[] = {GL_COLOR_ATTACHMENT0,
                                 GL_COLOR_ATTACHMENT1,
                                 GL_COLOR_ATTACHMENT2,
                                 GL_COLOR_ATTACHMENT3,
                                 projector ? GLenum{GL_COLOR_ATTACHMENT4} : GLenum{GL_NONE},
                                 GL_COLOR_ATTACHMENT5};
  glDrawBuffers(occlusion ? 6 : (projector ? 5 : 4), draw_buffers);
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
  if (projector) glClearBufferfv(GL_COLOR, 4, zero_z);
  if (occlusion) glClearBufferfv(GL_COLOR, 5, zero_z);
  glClearBufferfv(GL_DEPTH, 0, &far_depth);
  ForEachSurface(items, [&](const DrawItem& item, size_t index, const MeshBuffers& mesh,
                            const Material& material, GLsizei first, GLsizei count) {
    DrawPbrSurface(item, index, camera_from_world, mesh, material, first, count);
  });
  EnsureImage(&result->instance, height, width, CV_16UC1);
  EnsureImage(&result->depth_mm, height, width, CV_32FC1);
  EnsureImage(&result->color_linear, height, width, CV_32FC3);
  glReadBuffer(GL_COLOR_ATTACHMENT1);
  glReadPixels(0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_SHORT, result->instance.data);
  glReadBuffer(GL_COLOR_ATTACHMENT2);
  glReadPixels(0, 0, width, height, GL_RED, GL_FLOAT, result->depth_mm.data);
  if (projector) {
    EnsureImage(&result->projector_return, height, width, CV_32FC1);
    glReadBuffer(GL_COLOR_ATTACHMENT4);
    glReadPixels(0, 0, width, height, GL_RED, GL_FLOAT, result->projector_return.data);
  } else {
    result->projector_return.release();
  }
  if (samples <= 1) {
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    ReadLinearColor(&result->color_linear);
    if (occlusion) OccludeEnvironment(camera, options.environment_occlusion_mm, result);
    CompositeBackground(options, result);
  } else {
    // the surface each sample sees, four to a texel, and each centre's surface
    GLfloat positions[2 * 4] = {};
    ReadSampleSurfaces(camera, items, samples, camera_from_world, positions);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    ReadLinearColor(&result->color_linear);
    if (occlusion) OccludeEnvironment(camera, options.environment_occlusion_mm, result);
    CompositeBackground(options, result);
    ResolveEdges(centre_surfaces, sample_surfaces, samples, positions, &result->color_linear,
                 &edge_colors);
  }
  glBindVertexArray(0);
  result->color.release();
  CheckGlError("Renderer::Render (physically based)");
}

}  // namespace stackgen
