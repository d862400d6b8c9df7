#include <algorithm>

#include "gen/physics/pile_internal.h"

namespace stackgen {
namespace pile_internal {

std::vector<std::pair<int, double>> ReleaseQueue::Next(double time_s, std::vector<Box> boxes,
                                                       const std::vector<bool>& in_pile,
                                                       bool landed) {
  auto free_at = [&](const Release& r, double z) {
    const Box box = r.BoxAt(z);
    return std::none_of(boxes.begin(), boxes.end(),
                        [&](const Box& other) { return box.Overlaps(other, kReleaseGapMm); });
  };
  auto blocked_by_pile_only = [&](const Release& r) {
    Box column = r.BoxAt(release_z_mm_);
    column.hi.z() = HUGE_VAL;
    for (size_t b = 0; b < boxes.size(); ++b) {
      const bool resting = b < in_pile.size() && in_pile[b];
      if (!resting && column.Overlaps(boxes[b], kReleaseGapMm)) return false;
    }
    return true;
  };
  auto lowest_free = [&](const Release& r) {
    std::vector<double> heights = {release_z_mm_};
    for (const Box& box : boxes) heights.push_back(box.hi.z() + kReleaseGapMm);
    std::sort(heights.begin(), heights.end());
    for (double z : heights) {
      if (z >= release_z_mm_ && free_at(r, z)) return z;
    }
    return heights.back();  // unreachable: the highest candidate is always free
  };

  // sequential: the next part, once the previous one has landed
  if (sequential_) {
    if (waiting_.empty() || !landed) return {};
    const int part = waiting_.front();
    waiting_.erase(waiting_.begin());
    const Release& r = releases_[part];
    last_release_s_ = time_s;
    return {{part, free_at(r, release_z_mm_) ? release_z_mm_ : lowest_free(r)}};
  }

  // every waiting part in order; each released box blocks the ones after it
  const bool stalled = time_s - last_release_s_ >= kStallS;
  std::vector<std::pair<int, double>> released;
  std::vector<int> still_waiting;
  for (int part : waiting_) {
    const Release& r = releases_[part];
    double z = release_z_mm_;
    if (!free_at(r, z)) {
      if (!(stalled && released.empty()) && !blocked_by_pile_only(r)) {
        still_waiting.push_back(part);
        continue;
      }
      z = lowest_free(r);
    }
    released.emplace_back(part, z);
    boxes.push_back(r.BoxAt(z));
  }
  if (!released.empty()) last_release_s_ = time_s;
  waiting_ = std::move(still_waiting);
  return released;
}

}  // namespace pile_internal
}  // namespace stackgen
