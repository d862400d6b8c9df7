#include "gen/physics/settle_detector.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace stackgen {
namespace {

// slack on window boundaries, s, so sample times that are sums of steps compare as intended
constexpr double kTimeSlackS = 1e-9;

}  // namespace

SettleDetector::SettleDetector(double translation_mm, double rotation_deg, double window_s)
    : translation_mm_(translation_mm),
      rotation_rad_(rotation_deg * M_PI / 180),
      window_s_(window_s) {
  if (!(translation_mm > 0 && rotation_deg > 0 && window_s > 0)) {
    std::ostringstream message;
    message << "SettleDetector: thresholds must be > 0, got " << translation_mm << " mm, "
            << rotation_deg << " deg, " << window_s << " s";
    throw std::runtime_error(message.str());
  }
}

void SettleDetector::Reset() { window_.clear(); }

bool SettleDetector::AddSample(double time_s, const std::vector<Eigen::Isometry3d>& poses) {
  if (!window_.empty() && window_.front().position_mm.size() != poses.size()) {
    throw std::runtime_error("SettleDetector: the number of bodies changed from " +
                             std::to_string(window_.front().position_mm.size()) + " to " +
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
  bool settled = !window_.empty() && window_.front().time_s <= window_start_s;

  // every body within both thresholds of every sample
  for (size_t s = 0; settled && s < window_.size(); ++s) {
    const Sample& then = window_[s];
    for (size_t i = 0; settled && i < poses.size(); ++i) {
      settled = (now.position_mm[i] - then.position_mm[i]).norm() < translation_mm_ &&
                now.rotation[i].angularDistance(then.rotation[i]) < rotation_rad_;
    }
  }
  window_.push_back(std::move(now));
  return settled;
}

}  // namespace stackgen
