// Renderer's silhouette passes: every object's full mask, 32 objects a pass, one bit each.
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

}  // namespace stackgen
