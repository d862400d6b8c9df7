#pragma once

#include <deque>
#include <vector>

#include <Eigen/Geometry>

namespace stackgen {

/// When bodies count as at rest: every body moved less than translation_mm and turned less than
/// rotation_deg between every pose sample of the last window_s seconds and now (a sliding window
/// of poses, not velocities, so a slow creep or a rocking part is not at rest), within max_time_s
/// of simulated time. The one rule the pile simulator knows: it decides when a sequential drop's
/// part has landed, when a body rests in the pile, when a pile has landed, when it is published
/// at rest (SimulationParams' settle_*) and when a strict check ends (PileSimulator::Resettle).
/// A rotation_deg of 180 or more does not look at turning.
struct RestRule {
  double translation_mm = 0;
  double rotation_deg = 0;
  double window_s = 0;
  double max_time_s = 0;
};

/// Decides when bodies have come to rest by a RestRule, from their poses sampled at increasing
/// times. Bodies may be added between samples (a part released into the pile): a body is at rest
/// once its own samples span the window.
class SettleDetector {
 public:
  /// Throws std::runtime_error unless the rule's thresholds and window are > 0 (max_time_s is
  /// the caller's).
  explicit SettleDetector(const RestRule& rule);

  /// Adds the poses (millimetres) of all bodies at `time_s` (seconds, increasing between calls;
  /// the bodies of the last sample first, in the same order, then any added since) and returns
  /// whether every body is at rest. Throws std::runtime_error if there are fewer bodies than
  /// before without Reset().
  bool AddSample(double time_s, const std::vector<Eigen::Isometry3d>& poses);

  /// Whether body `i` was at rest at the last sample (false for a body not sampled).
  bool AtRest(size_t i) const { return i < at_rest_.size() && at_rest_[i]; }

  /// Forgets all samples (the window starts again).
  void Reset();

 private:
  struct Sample {
    double time_s = 0;
    std::vector<Eigen::Vector3d> position_mm;
    std::vector<Eigen::Quaterniond> rotation;
  };

  double translation_mm_;
  double rotation_rad_;
  double window_s_;
  std::deque<Sample> window_;
  std::vector<bool> at_rest_;  // per body, at the last sample
};

}  // namespace stackgen
