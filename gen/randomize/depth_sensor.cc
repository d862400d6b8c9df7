#include "gen/randomize/depth_sensor.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "gen/randomize/uniform.h"

namespace stackgen {

namespace {

// throws unless `image` is rows x cols of `type`
void CheckImage(const cv::Mat& image, int type, const cv::Mat& like, const std::string& what) {
  if (image.type() != type || image.rows != like.rows || image.cols != like.cols) {
    throw std::invalid_argument(what + " must be " + std::to_string(like.cols) + " x " +
                                std::to_string(like.rows) + " of OpenCV type " +
                                std::to_string(type) + ", got " + std::to_string(image.cols) +
                                " x " + std::to_string(image.rows) + " of type " +
                                std::to_string(image.type()));
  }
}

}  // namespace

DepthSensorModel DepthSensorOf(const config::Sensor3dConfig& config) {
  DepthSensorModel model;
  model.baseline_mm = config.baseline_mm();
  model.noise_at_1m_mm = config.noise_at_1m_mm();
  model.min_return = config.min_return();
  model.max_return = config.max_return();
  model.edge_step_mm = config.edge_step_mm();
  model.flying_pixel_probability = config.flying_pixel_probability();
  model.quantization_mm = config.quantization_mm();
  model.subsample = config.subsample();
  return model;
}

CameraModel ProjectorCamera(const CameraModel& camera, double baseline_mm, double nearest_mm) {
  if (!(std::isfinite(baseline_mm) && baseline_mm != 0) ||
      !(std::isfinite(nearest_mm) && nearest_mm > 0)) {
    throw std::invalid_argument("ProjectorCamera: baseline_mm " + std::to_string(baseline_mm) +
                                " must be finite and not 0, nearest_mm " +
                                std::to_string(nearest_mm) + " finite and positive");
  }
  // a point at camera z >= nearest shifts by at most fx |b| / nearest pixels in the projector's
  // image at the camera's focal length: scale the focal lengths so that the camera's width and
  // that shift fit in the image, a pixel to spare on either side
  const double shift = camera.fx * std::abs(baseline_mm) / nearest_mm;
  const double s = (camera.width - 3) / (camera.width - 1 + shift);
  CameraModel projector = camera;
  projector.fx = s * camera.fx;
  projector.fy = s * camera.fy;
  projector.cx = 1 + s * (camera.cx + (baseline_mm > 0 ? shift : 0));
  projector.cy = s * camera.cy + (1 - s) * (camera.height - 1) / 2;
  projector.world_from_camera =
      camera.world_from_camera * Eigen::Translation3d(baseline_mm, 0, 0);
  return projector;
}

cv::Mat ProjectorVisible(const cv::Mat& depth_mm, const Intrinsics& camera,
                         const cv::Mat& projector_depth_mm, const Intrinsics& projector,
                         double baseline_mm) {
  if (depth_mm.type() != CV_32FC1 || depth_mm.cols != camera.width ||
      depth_mm.rows != camera.height) {
    throw std::invalid_argument("ProjectorVisible: depth_mm must be the camera's size, CV_32FC1");
  }
  if (projector_depth_mm.type() != CV_32FC1 || projector_depth_mm.cols != projector.width ||
      projector_depth_mm.rows != projector.height) {
    throw std::invalid_argument(
        "ProjectorVisible: projector_depth_mm must be the projector's size, CV_32FC1");
  }
  cv::Mat visible(depth_mm.size(), CV_8UC1, cv::Scalar(0));
  const int pw = projector.width, ph = projector.height;
  for (int v = 0; v < depth_mm.rows; ++v) {
    const float* depth = depth_mm.ptr<float>(v);
    uint8_t* out = visible.ptr<uint8_t>(v);
    for (int u = 0; u < depth_mm.cols; ++u) {
      const double z = depth[u];
      if (z <= 0) continue;
      // the point in the projector's frame (the same orientation, moved along x), and where it
      // lands in the projector's image
      const double x = (u - camera.cx) * z / camera.fx - baseline_mm;
      const double y = (v - camera.cy) * z / camera.fy;
      const double pu = projector.fx * x / z + projector.cx;
      const double pv = projector.fy * y / z + projector.cy;
      const int u0 = static_cast<int>(std::floor(pu)), v0 = static_cast<int>(std::floor(pv));
      if (u0 < 0 || v0 < 0 || u0 + 1 >= pw || v0 + 1 >= ph) continue;
      // lit when one of the four projector pixels around it sees it or something behind it
      const float reach = static_cast<float>(z - std::max(0.5, 0.002 * z));
      const float* row0 = projector_depth_mm.ptr<float>(v0);
      const float* row1 = projector_depth_mm.ptr<float>(v0 + 1);
      const float seen[4] = {row0[u0], row0[u0 + 1], row1[u0], row1[u0 + 1]};
      for (const float s : seen) {
        if (s >= reach) {
          out[u] = 255;
          break;
        }
      }
    }
  }
  return visible;
}

cv::Mat SensorDepth(const cv::Mat& ideal_mm, const cv::Mat& visible,
                    const cv::Mat& projector_return, const DepthSensorModel& model,
                    std::mt19937_64& engine) {
  if (ideal_mm.type() != CV_32FC1) {
    throw std::invalid_argument("SensorDepth: ideal_mm must be CV_32FC1");
  }
  CheckImage(visible, CV_8UC1, ideal_mm, "SensorDepth: visible");
  CheckImage(projector_return, CV_32FC1, ideal_mm, "SensorDepth: projector_return");
  const int rows = ideal_mm.rows, cols = ideal_mm.cols;

  // 1. measured where the exact depth exists, the projector lights it and enough, not too much,
  // of its pattern comes back
  cv::Mat depth(ideal_mm.size(), CV_32FC1, cv::Scalar(0));
  for (int v = 0; v < rows; ++v) {
    const float* ideal = ideal_mm.ptr<float>(v);
    const uint8_t* lit = visible.ptr<uint8_t>(v);
    const float* back = projector_return.ptr<float>(v);
    float* out = depth.ptr<float>(v);
    for (int u = 0; u < cols; ++u) {
      const bool measured = ideal[u] > 0 && lit[u] != 0 && back[u] >= model.min_return &&
                            back[u] <= model.max_return;
      out[u] = measured ? ideal[u] : 0.f;
    }
  }

  // 2. flying pixels: across a step to a neighbour, between the two depths
  if (model.flying_pixel_probability > 0) {
    const int du[4] = {-1, 1, 0, 0}, dv[4] = {0, 0, -1, 1};
    for (int v = 0; v < rows; ++v) {
      const float* ideal = ideal_mm.ptr<float>(v);
      float* out = depth.ptr<float>(v);
      for (int u = 0; u < cols; ++u) {
        if (out[u] == 0) continue;
        float step = 0, other = 0;
        for (int k = 0; k < 4; ++k) {
          const int nu = u + du[k], nv = v + dv[k];
          if (nu < 0 || nv < 0 || nu >= cols || nv >= rows) continue;
          const float neighbour = ideal_mm.at<float>(nv, nu);
          if (neighbour > 0 && std::abs(neighbour - ideal[u]) > step) {
            step = std::abs(neighbour - ideal[u]);
            other = neighbour;
          }
        }
        if (step <= model.edge_step_mm) continue;
        if (Uniform01(engine) >= model.flying_pixel_probability) continue;
        out[u] = static_cast<float>(ideal[u] + Uniform01(engine) * (other - ideal[u]));
      }
    }
  }

  // 3. axial noise, growing with the square of the distance (Box-Muller, two values a pair)
  if (model.noise_at_1m_mm > 0) {
    double spare = 0;
    bool has_spare = false;
    for (int v = 0; v < rows; ++v) {
      float* out = depth.ptr<float>(v);
      for (int u = 0; u < cols; ++u) {
        if (out[u] == 0) continue;
        double normal = spare;
        if (!has_spare) {
          const double radius = std::sqrt(-2 * std::log(1 - Uniform01(engine)));
          const double angle = 2 * M_PI * Uniform01(engine);
          normal = radius * std::cos(angle);
          spare = radius * std::sin(angle);
        }
        has_spare = !has_spare;
        const double z_m = out[u] / 1000.0;
        const double noisy = out[u] + normal * model.noise_at_1m_mm * z_m * z_m;
        out[u] = static_cast<float>(std::max(noisy, 1e-3));
      }
    }
  }

  // 4. lateral resolution: each block takes its centre pixel's value
  const int k = std::max(model.subsample, 1);
  if (k > 1) {
    for (int v0 = 0; v0 < rows; v0 += k) {
      for (int u0 = 0; u0 < cols; u0 += k) {
        const int centre_v = std::min(v0 + k / 2, rows - 1);
        const int centre_u = std::min(u0 + k / 2, cols - 1);
        const float value = depth.at<float>(centre_v, centre_u);
        for (int v = v0; v < std::min(v0 + k, rows); ++v) {
          float* out = depth.ptr<float>(v);
          for (int u = u0; u < std::min(u0 + k, cols); ++u) out[u] = value;
        }
      }
    }
  }

  // 5. the sensor's depth resolution
  if (model.quantization_mm > 0) {
    const double q = model.quantization_mm;
    for (int v = 0; v < rows; ++v) {
      float* out = depth.ptr<float>(v);
      for (int u = 0; u < cols; ++u) {
        if (out[u] != 0) out[u] = static_cast<float>(std::max(std::round(out[u] / q), 1.0) * q);
      }
    }
  }
  return depth;
}

}  // namespace stackgen
