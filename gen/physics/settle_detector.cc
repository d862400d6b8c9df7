#include "gen/physics/settle_detector.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace stackgen {
namespace {

// slack on window boundaries, s, so sample times that are sums of steps compare as intended
constexpr double kTimeSlackS = 1e-9;

}  // namespace

SettleDetector::SettleDetector(const RestRule& rule)
    : translation_mm_(rule.translation_mm),
      rotation_rad_(rule.rotation_deg * M_PI / 180),
      window_s_(rule.window_s) {
  if (!(rule.translation_mm > 0 && rule.rotation_deg > 0 && rule.window_s > 0)) {
    std::ostringstream message;
    message << "SettleDetector: thresholds must be > 0, got " << rule.translation_mm << " mm, "
            << rule.rotation_deg << " deg, " << rule.window_s << " s";
    throw std::runtime_error(message.str());
  }
}

void SettleDetector::Reset() {
  window_.clear();
  at_rest_.clear();
}

bool SettleDetector::AddSample(double time_s, const std::vector<Eigen::Isometry3d>& poses) {
  if (!window_.empty() && window_.back().position_mm.size() > poses.size()) {
    throw std::runtime_error("SettleDetector: the number of bodies fell from " +
                             std::to_string(window_.back().position_mm.size()) + " to " +
                             std::to_string(poses.size()) + " without Reset()");
  }
  Sample now;
  now.time_s = time_s;
  for (const auto& pose : poses) {
    now.position_mm.push_back(pose.translation());
    now.rotation.emplace_back(pose.linear());
  }

  // keep the samples of the window plus the last one before it, so the samples reach back a
  // full window whatever the sampling interval
  const double window_start_s = time_s - window_s_ + kTimeSlackS;
  while (window_.size() >= 2 && window_[1].time_s <= window_start_s) window_.pop_front();
  const bool spans = !window_.empty() && window_.front().time_s <= window_start_s;

  // a body is at rest when its samples span the window (it was in the oldest one) and it is
  // within both thresholds of every sample (compared squared, and the turn by the quaternions'
  // dot product, |q1 . q2| being the cosine of half the angle between them: no square root or
  // arc tangent per sample)
  const double translation2 = translation_mm_ * translation_mm_;
  const double min_cos_half = std::cos(rotation_rad_ / 2);
  at_rest_.assign(poses.size(), false);
  bool all = true;
  for (size_t i = 0; i < poses.size(); ++i) {
    bool still = spans && i < window_.front().position_mm.size();
    for (size_t s = 0; still && s < window_.size(); ++s) {
      const Sample& then = window_[s];
      still =
          (now.position_mm[i] - then.position_mm[i]).squaredNorm() < translation2 &&
          (rotation_rad_ >= M_PI || std::abs(now.rotation[i].dot(then.rotation[i])) > min_cos_half);
    }
    at_rest_[i] = still;
    all = all && still;
  }
  window_.push_back(std::move(now));
  return all && spans;
}

}  // namespace stackgen
