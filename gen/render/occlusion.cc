#include "gen/render/occlusion.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/utility.hpp>

namespace stackgen {
namespace {

constexpr int kDirections = 8;  // around each pixel: 4 slices, both sides
constexpr int kSteps = 6;       // samples along each direction
constexpr int kCoarse = 4;      // the horizons are found at every kCoarse-th pixel and row
// a horizon must rise this much (sine of its angle) over the tangent plane to hide anything,
// so that the depth's rounding on a flat face hides nothing
constexpr float kBias = 0.03f;
// neighbours are the same surface when their depths differ by less than this share
constexpr float kSameSurface = 0.03f;
// the share of the radius over which a horizon's weight falls from 1 to 0
constexpr float kFade = 0.4f;

// a 4 x 4 ordered pattern: each pixel of a 4 x 4 block gets its own turn of the directions and
// start along them, and the blur over the block averages them
constexpr int kPattern[16] = {0, 8, 2, 10, 12, 4, 14, 6, 3, 11, 1, 9, 15, 7, 13, 5};

// the camera's intrinsics as the loops use them
struct Pinhole {
  float cx, cy, inverse_fx, inverse_fy;
  explicit Pinhole(const Intrinsics& camera)
      : cx(static_cast<float>(camera.cx)),
        cy(static_cast<float>(camera.cy)),
        inverse_fx(static_cast<float>(1 / camera.fx)),
        inverse_fy(static_cast<float>(1 / camera.fy)) {}
};

Eigen::Vector3f PositionAt(const cv::Mat& depth, const Pinhole& camera, int u, int v) {
  const float z = depth.at<float>(v, u);
  return {(static_cast<float>(u) - camera.cx) * z * camera.inverse_fx,
          (static_cast<float>(v) - camera.cy) * z * camera.inverse_fy, z};
}

// the surface's normal at (u, v) from its neighbours' depths, on each axis the side whose depth
// is nearer its own (a step in depth is another surface), turned towards the camera
Eigen::Vector3f NormalAt(const cv::Mat& depth, const Pinhole& camera, int u, int v,
                         const Eigen::Vector3f& p) {
  const auto along = [&](int du, int dv) -> Eigen::Vector3f {
    const int u0 = u - du, v0 = v - dv, u1 = u + du, v1 = v + dv;
    const bool has0 = u0 >= 0 && v0 >= 0 && depth.at<float>(v0, u0) > 0;
    const bool has1 = u1 < depth.cols && v1 < depth.rows && depth.at<float>(v1, u1) > 0;
    if (has1 && (!has0 || std::abs(depth.at<float>(v1, u1) - p.z()) <=
                              std::abs(depth.at<float>(v0, u0) - p.z()))) {
      return PositionAt(depth, camera, u1, v1) - p;
    }
    if (has0) return p - PositionAt(depth, camera, u0, v0);
    return Eigen::Vector3f::Zero();
  };
  Eigen::Vector3f n = along(1, 0).cross(along(0, 1));
  if (n.squaredNorm() == 0) return -p.normalized();
  n.normalize();
  return n.dot(p) > 0 ? -n : n;
}

}  // namespace

void EnvironmentVisibility(const cv::Mat& depth_mm, const Intrinsics& camera, double radius_mm,
                           cv::Mat* visibility) {
  if (depth_mm.type() != CV_32FC1 || depth_mm.cols != camera.width ||
      depth_mm.rows != camera.height) {
    throw std::invalid_argument("EnvironmentVisibility: depth_mm must be CV_32FC1 of " +
                                std::to_string(camera.width) + " x " +
                                std::to_string(camera.height));
  }
  if (!(radius_mm > 0) || !std::isfinite(radius_mm)) {
    throw std::invalid_argument("EnvironmentVisibility: radius_mm " + std::to_string(radius_mm) +
                                " must be finite and > 0");
  }
  const int width = depth_mm.cols;
  const int height = depth_mm.rows;
  const int coarse_width = (width + kCoarse - 1) / kCoarse;
  const int coarse_height = (height + kCoarse - 1) / kCoarse;
  const float radius = static_cast<float>(radius_mm);
  const float radius_squared = radius * radius;
  // what lies in the outer 40 % of the radius counts less the farther it is
  const float fade = 1.f / (kFade * radius);
  const float max_reach_px = 0.5f * static_cast<float>(std::max(width, height));

  const Pinhole pinhole(camera);
  // the directions, for each turn of the pattern
  float directions[16][kDirections][2];
  for (int k = 0; k < 16; ++k) {
    for (int d = 0; d < kDirections; ++d) {
      const double angle = 2 * M_PI * (d + (k + 0.5) / 16) / kDirections;
      directions[k][d][0] = static_cast<float>(std::cos(angle));
      directions[k][d][1] = static_cast<float>(std::sin(angle));
    }
  }

  // the open share of the sky at every kCoarse-th pixel of every kCoarse-th row
  cv::Mat open(coarse_height, coarse_width, CV_32FC1);
  cv::Mat coarse_depth(coarse_height, coarse_width, CV_32FC1);
  cv::parallel_for_(cv::Range(0, coarse_height), [&](const cv::Range& rows) {
    for (int j = rows.start; j < rows.end; ++j) {
      for (int i = 0; i < coarse_width; ++i) {
        const int u = kCoarse * i;
        const int v = kCoarse * j;
        const float z = depth_mm.at<float>(v, u);
        coarse_depth.at<float>(j, i) = z;
        if (z <= 0) {
          open.at<float>(j, i) = 1;
          continue;
        }
        const Eigen::Vector3f p = PositionAt(depth_mm, pinhole, u, v);
        const Eigen::Vector3f n = NormalAt(depth_mm, pinhole, u, v, p);
        const int pattern = kPattern[(i & 3) + 4 * (j & 3)];
        const float start = ((pattern * 5) % 16 + 0.5f) / 16.f;
        const float reach_px = std::min(max_reach_px, static_cast<float>(radius * camera.fx / z));
        float open_sum = 0;
        for (int d = 0; d < kDirections; ++d) {
          const float du = directions[pattern][d][0];
          const float dv = directions[pattern][d][1];
          float rise = 0;  // sine of the horizon's angle over the tangent plane, weighted
          for (int s = 0; s < kSteps; ++s) {
            // denser near the pixel, where the nearest walls stand
            const float step = (s + start) / kSteps;
            const float t = std::max(1.f, reach_px * step * step);
            const int qu = cvRound(static_cast<float>(u) + du * t);
            const int qv = cvRound(static_cast<float>(v) + dv * t);
            if (qu < 0 || qv < 0 || qu >= width || qv >= height) break;
            if (depth_mm.at<float>(qv, qu) <= 0) continue;
            const Eigen::Vector3f w = PositionAt(depth_mm, pinhole, qu, qv) - p;
            const float distance_squared = w.squaredNorm();
            if (distance_squared >= radius_squared || distance_squared == 0) continue;
            const float distance = std::sqrt(distance_squared);
            const float sine = w.dot(n) / distance - kBias;
            rise = std::max(rise, sine * std::min(1.f, (radius - distance) * fade));
          }
          rise = std::min(rise, 1.f);
          open_sum += std::sqrt(1 - rise * rise);  // cos h: 1 - (1 - cos h) hidden
        }
        open.at<float>(j, i) = open_sum / kDirections;
      }
    }
  });

  // averaged over the pattern's 4 x 4 block, between pixels of the same surface
  cv::Mat smooth(coarse_height, coarse_width, CV_32FC1);
  cv::parallel_for_(cv::Range(0, coarse_height), [&](const cv::Range& rows) {
    for (int j = rows.start; j < rows.end; ++j) {
      for (int i = 0; i < coarse_width; ++i) {
        const float z = coarse_depth.at<float>(j, i);
        if (z <= 0) {
          smooth.at<float>(j, i) = 1;
          continue;
        }
        float sum = 0;
        int count = 0;
        for (int b = std::max(0, j - 2); b <= std::min(coarse_height - 1, j + 1); ++b) {
          for (int a = std::max(0, i - 2); a <= std::min(coarse_width - 1, i + 1); ++a) {
            const float other = coarse_depth.at<float>(b, a);
            if (other <= 0 || std::abs(other - z) > kSameSurface * z) continue;
            sum += open.at<float>(b, a);
            ++count;
          }
        }
        smooth.at<float>(j, i) = sum / static_cast<float>(count);
      }
    }
  });

  // full size: the four coarse pixels around, bilinear, those of the same surface only (the
  // nearest in depth where none is)
  visibility->create(height, width, CV_32FC1);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      const int j0 = std::min(v / kCoarse, coarse_height - 1);
      const int j1 = std::min(j0 + 1, coarse_height - 1);
      const float fy = static_cast<float>(v) / kCoarse - static_cast<float>(j0);
      float* out = visibility->ptr<float>(v);
      for (int u = 0; u < width; ++u) {
        const float z = depth_mm.at<float>(v, u);
        if (z <= 0) {
          out[u] = 1;
          continue;
        }
        const int i0 = std::min(u / kCoarse, coarse_width - 1);
        const int i1 = std::min(i0 + 1, coarse_width - 1);
        const float fx = static_cast<float>(u) / kCoarse - static_cast<float>(i0);
        const int is[4] = {i0, i1, i0, i1};
        const int js[4] = {j0, j0, j1, j1};
        const float weights[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
        float sum = 0;
        float total = 0;
        float nearest_gap = -1;
        float nearest = 1;
        for (int k = 0; k < 4; ++k) {
          const float other = coarse_depth.at<float>(js[k], is[k]);
          const float gap = std::abs(other - z);
          if (nearest_gap < 0 || gap < nearest_gap) {
            nearest_gap = gap;
            nearest = smooth.at<float>(js[k], is[k]);
          }
          if (other <= 0 || gap > kSameSurface * z) continue;
          sum += weights[k] * smooth.at<float>(js[k], is[k]);
          total += weights[k];
        }
        out[u] = total > 1e-6f ? sum / total : nearest;
      }
    }
  });
}

}  // namespace stackgen
