#pragma once

// Parallel-jaw grasps: two fingers closing on a part across it, found from a contact the
// camera sees (GraspScene::SeenPoints): the ray into the part along the contact's inward normal
// leaves it at the second contact; the pair is antipodal when the line between them lies inside
// both contacts' friction cones (Nguyen 1988; Dex-Net 2.0's antipodal sampling, Mahler et al.
// 2017); the fingers come in perpendicular to that line, from the viewer's side, and must find
// room beside both contacts.

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "gen/grasp/grasp_scene.h"

namespace stackgen {

/// The gripper (config GraspConfig).
struct JawGripper {
  double max_width_mm = 80;     // the widest the jaws open, > 0
  double finger_width_mm = 10;  // each finger's size across and along the closing line, > 0
  double friction = 0.5;        // Coulomb coefficient between finger and part, > 0
  double approach_mm = 150;     // the fingers' clear length along the approach, > 0
};

/// One evaluated parallel-jaw grasp.
struct JawGrasp {
  Eigen::Vector3d point_a_mm{0, 0, 0};  // the contact seen, world frame
  Eigen::Vector3d point_b_mm{0, 0, 0};  // the contact across the part
  /// Unit direction the gripper moves in to close on the part (perpendicular to the line a-b).
  Eigen::Vector3d approach{0, 0, -1};
  int u = 0, v = 0;     // the pixel (or grid cell) contact a was found at
  double width_mm = 0;  // |b - a|
  /// How far inside the friction cones the closing line lies: atan(friction) less the larger
  /// of the angles between the line and each contact's inward normal, degrees (> 0).
  double cone_margin_deg = 0;
  /// Distance along -approach to the first thing either finger (three lines each, across its
  /// width) would meet, mm; approach_mm when nothing; 0 when something already fills the room
  /// a finger needs beside its contact.
  double clearance_mm = 0;
  bool approach_clear = false;  // clearance_mm >= approach_mm
  /// Distance of the part's centre of mass from the closing line, mm: the lever that turns it
  /// between the fingers.
  double com_offset_mm = 0;
};

/// Orders grasps best first: approach clear before blocked, then the larger cone margin, then
/// the smaller lever, then pixel (v, u).
bool BetterJaw(const JawGrasp& a, const JawGrasp& b);

/// The antipodal grasp of `object` through `contact` (world, mm), the gripper coming from
/// `toward_gripper` (a unit direction from the part to where the gripper is: the camera's side,
/// or up): none when the ray along the inward normal does not leave the object within
/// max_width_mm, the pair is not inside both friction cones, or the gripper would have to come
/// in along the closing line.
std::optional<JawGrasp> EvaluateJaw(const GraspScene& scene, const SurfacePoint& contact,
                                    int object, const Eigen::Vector3d& com_world,
                                    const Eigen::Vector3d& toward_gripper,
                                    const JawGripper& gripper);

/// The antipodal grasps at `contacts`, the gripper coming from `viewer` (the camera's centre: each
/// contact's own direction to it), ordered best first (BetterJaw).
std::vector<JawGrasp> JawGrasps(const GraspScene& scene, const std::vector<SurfacePoint>& contacts,
                                int object, const Eigen::Vector3d& com_world,
                                const Eigen::Vector3d& viewer, const JawGripper& gripper);

}  // namespace stackgen
