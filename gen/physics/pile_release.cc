#include <algorithm>
#include <random>

#include "gen/physics/pile_internal.h"
#include "gen/randomize/uniform.h"

namespace stackgen {
namespace pile_internal {

// How each part drops, all drawn now from `engine`: orientation, bounding box, and x, y inside
// the opening (centred where the box is wider than the bin; sequential: centred on the drop
// point, kept inside the opening where it fits).
std::vector<Release> DrawReleases(const std::vector<TypeModel>& type_models,
                                  const std::vector<int>& types, const BinSpec& bin,
                                  const SimulationParams& params, std::mt19937_64& engine) {
  const bool sequential = params.drop_mode == DropMode::kSequential;
  std::vector<Release> releases;
  const double half_inner[2] = {bin.inner_length_mm / 2, bin.inner_width_mm / 2};
  for (int type : types) {
    Release release;
    release.type = type;
    release.world_from_object_rotation = UniformRotation(engine);
    Box box;
    for (const auto& v : type_models[type].hull_vertices_mm) {
      box.Add(release.world_from_object_rotation * v);
    }
    release.object_origin_in_box_mm = -box.lo;
    release.size_mm = box.hi - box.lo;
    for (int axis = 0; axis < 2; ++axis) {
      const double room = 2 * (half_inner[axis] - kReleaseWallMarginMm) - release.size_mm[axis];
      const double lowest = -half_inner[axis] + kReleaseWallMarginMm;
      if (room <= 0) {
        release.box_lo_xy_mm[axis] = -release.size_mm[axis] / 2;
      } else if (sequential) {
        release.box_lo_xy_mm[axis] = std::clamp(
            params.drop_point_mm[axis] - release.size_mm[axis] / 2, lowest, lowest + room);
      } else {
        release.box_lo_xy_mm[axis] = lowest + Uniform01(engine) * room;
      }
    }
    releases.push_back(release);
  }
  return releases;
}

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
