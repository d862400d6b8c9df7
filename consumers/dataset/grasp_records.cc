#include "consumers/dataset/grasp_records.h"

#include <algorithm>
#include <vector>

namespace stackgen {

using nlohmann::json;

json SuctionGraspsJson(const scene& scene, int32_t instance_id) {
  std::vector<const suction_grasp*> own;
  for (const suction_grasp& grasp : scene.suction_grasps) {
    if (grasp.instance_id == instance_id) own.push_back(&grasp);
  }
  std::sort(own.begin(), own.end(), [](const suction_grasp* a, const suction_grasp* b) {
    return a->rank < b->rank;
  });
  json out = json::array();
  for (const suction_grasp* grasp : own) {
    static const char* const kProofs[] = {"not tried", "lifted", "dropped", "stuck"};
    json record = {{"rank", grasp->rank},
                   {"point_mm", std::vector<double>(grasp->point_mm, grasp->point_mm + 3)},
                   {"normal", std::vector<double>(grasp->normal, grasp->normal + 3)},
                   {"u", grasp->u},
                   {"v", grasp->v},
                   {"seal", grasp->seal},
                   {"clearance_mm", grasp->clearance_mm},
                   {"approach_clear", grasp->approach_clear != 0},
                   {"com_offset_mm", grasp->com_offset_mm},
                   {"proof", kProofs[std::clamp<int>(grasp->proof, 0, 3)]}};
    if (grasp->proof != suction_grasp::PROOF_NOT_TRIED) {
      record["proof_swing_deg"] = grasp->proof_swing_deg;
      record["proof_neighbours_moved_mm"] = grasp->proof_neighbours_moved_mm;
      record["moved_instance_ids"] = std::vector<int32_t>(
          grasp->moved_instance_ids, grasp->moved_instance_ids + std::min(grasp->num_moved, 8));
      record["num_moved"] = grasp->num_moved;
    }
    out.push_back(std::move(record));
  }
  return out;
}

}  // namespace stackgen
