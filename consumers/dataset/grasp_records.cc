#include "consumers/dataset/grasp_records.h"

#include <algorithm>
#include <vector>

namespace stackgen {

using nlohmann::json;

namespace {

// the grasps of `instance_id` among `all`, by rank
template <typename Grasp>
std::vector<const Grasp*> GraspsOf(const std::vector<Grasp>& all, int32_t instance_id) {
  std::vector<const Grasp*> own;
  for (const Grasp& grasp : all) {
    if (grasp.instance_id == instance_id) own.push_back(&grasp);
  }
  std::sort(own.begin(), own.end(),
            [](const Grasp* a, const Grasp* b) { return a->rank < b->rank; });
  return own;
}

// the proof's fields of a grasp of either kind, into `record`
template <typename Grasp>
void AddProof(const Grasp& grasp, json* record) {
  static const char* const kProofs[] = {"not tried", "lifted", "dropped", "stuck"};
  (*record)["proof"] = kProofs[std::clamp<int>(grasp.proof, 0, 3)];
  if (grasp.proof == suction_grasp::PROOF_NOT_TRIED) return;
  (*record)["proof_swing_deg"] = grasp.proof_swing_deg;
  (*record)["proof_neighbours_moved_mm"] = grasp.proof_neighbours_moved_mm;
  (*record)["moved_instance_ids"] = std::vector<int32_t>(
      grasp.moved_instance_ids, grasp.moved_instance_ids + std::min(grasp.num_moved, 8));
  (*record)["num_moved"] = grasp.num_moved;
}

}  // namespace

json SuctionGraspsJson(const scene& scene, int32_t instance_id) {
  json out = json::array();
  for (const suction_grasp* grasp : GraspsOf(scene.suction_grasps, instance_id)) {
    json record = {{"rank", grasp->rank},
                   {"point_mm", std::vector<double>(grasp->point_mm, grasp->point_mm + 3)},
                   {"normal", std::vector<double>(grasp->normal, grasp->normal + 3)},
                   {"u", grasp->u},
                   {"v", grasp->v},
                   {"seal", grasp->seal},
                   {"clearance_mm", grasp->clearance_mm},
                   {"approach_clear", grasp->approach_clear != 0},
                   {"com_offset_mm", grasp->com_offset_mm}};
    AddProof(*grasp, &record);
    out.push_back(std::move(record));
  }
  return out;
}

json JawGraspsJson(const scene& scene, int32_t instance_id) {
  json out = json::array();
  for (const jaw_grasp* grasp : GraspsOf(scene.jaw_grasps, instance_id)) {
    json record = {{"rank", grasp->rank},
                   {"point_a_mm", std::vector<double>(grasp->point_a_mm, grasp->point_a_mm + 3)},
                   {"point_b_mm", std::vector<double>(grasp->point_b_mm, grasp->point_b_mm + 3)},
                   {"approach", std::vector<double>(grasp->approach, grasp->approach + 3)},
                   {"u", grasp->u},
                   {"v", grasp->v},
                   {"width_mm", grasp->width_mm},
                   {"cone_margin_deg", grasp->cone_margin_deg},
                   {"clearance_mm", grasp->clearance_mm},
                   {"approach_clear", grasp->approach_clear != 0},
                   {"com_offset_mm", grasp->com_offset_mm}};
    AddProof(*grasp, &record);
    out.push_back(std::move(record));
  }
  return out;
}

json GraspsJson(const scene& scene, int32_t instance_id) {
  json out = json::object();
  json suction = SuctionGraspsJson(scene, instance_id);
  if (!suction.empty()) out["suction_grasps"] = std::move(suction);
  json jaws = JawGraspsJson(scene, instance_id);
  if (!jaws.empty()) out["parallel_jaw_grasps"] = std::move(jaws);
  return out;
}

}  // namespace stackgen
