#pragma once
// A scene's suction grasps (scene.suction_grasps, config grasps) as the dataset writers store
// them: one JSON array per instance, best first (COCO: the annotation's "stackgen" block; BOP:
// scene_grasp.json beside scene_gt.json).

#include <cstdint>

#include <nlohmann/json.hpp>
#include <stackgen/scene.hpp>

namespace stackgen {

/// The grasps of instance `instance_id` in `scene`, ordered by rank: each
///   {"rank", "point_mm" [x, y, z] (camera frame), "normal" [x, y, z], "u", "v", "seal",
///    "clearance_mm", "approach_clear", "com_offset_mm", "proof": "not tried" | "lifted" |
///    "dropped" | "stuck", and when tried "proof_swing_deg", "proof_neighbours_moved_mm",
///    "moved_instance_ids" (at most 8, most moved first), "num_moved"}.
/// An empty array when it has none.
nlohmann::json SuctionGraspsJson(const scene& scene, int32_t instance_id);

}  // namespace stackgen
