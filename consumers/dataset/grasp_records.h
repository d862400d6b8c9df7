#pragma once
// A scene's grasps (scene.suction_grasps and jaw_grasps, config grasps) as the dataset writers
// store them: per instance, an object of one JSON array per kind, best first (COCO: the
// annotation's "stackgen" block; BOP: scene_grasp.json beside scene_gt.json).

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

/// The parallel-jaw grasps of instance `instance_id` in `scene`, ordered by rank: each
///   {"rank", "point_a_mm", "point_b_mm", "approach" (camera frame), "u", "v", "width_mm",
///    "cone_margin_deg", "clearance_mm", "approach_clear", "com_offset_mm", "proof" and, when
///    tried, the proof's fields as for suction}.
nlohmann::json JawGraspsJson(const scene& scene, int32_t instance_id);

/// Both kinds of grasps of instance `instance_id`: {"suction_grasps": [...],
/// "parallel_jaw_grasps": [...]}, each key only when the instance has grasps of that kind (an
/// empty object when it has none at all).
nlohmann::json GraspsJson(const scene& scene, int32_t instance_id);

}  // namespace stackgen
