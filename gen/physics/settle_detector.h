#pragma once

#include <deque>
#include <vector>

#include <Eigen/Geometry>

namespace stackgen {

/// Decides when a set of bodies has come to rest: settled once every body's position moved less
/// than `translation_mm` and its orientation turned less than `rotation_deg` between every sample
/// of the last `window_s` seconds and now (a sliding window of pose samples, not velocities, so a
/// slow creep or a rocking part does not count as settled).
class SettleDetector {
 public:
  /// Thresholds in millimetres, degrees and seconds; throws std::runtime_error unless all are > 0.
  SettleDetector(double translation_mm, double rotation_deg, double window_s);

  /// Adds the poses (millimetres) of all bodies at `time_s` (seconds, increasing between calls)
  /// and returns whether they have settled: the samples span at least the window and none moved
  /// past a threshold within it. Throws std::runtime_error if the number of bodies changes
  /// without Reset().
  bool AddSample(double time_s, const std::vector<Eigen::Isometry3d>& poses);

  /// Forgets all samples (e.g. after a body was added).
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
};

}  // namespace stackgen
