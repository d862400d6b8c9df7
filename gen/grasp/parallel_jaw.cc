#include "gen/grasp/parallel_jaw.h"

#include <algorithm>
#include <cmath>
#include <tuple>

namespace stackgen {

bool BetterJaw(const JawGrasp& a, const JawGrasp& b) {
  return std::make_tuple(!a.approach_clear, -a.cone_margin_deg, a.com_offset_mm, a.v, a.u) <
         std::make_tuple(!b.approach_clear, -b.cone_margin_deg, b.com_offset_mm, b.v, b.u);
}

std::optional<JawGrasp> EvaluateJaw(const GraspScene& scene, const SurfacePoint& contact,
                                    int object, const Eigen::Vector3d& com_world,
                                    const Eigen::Vector3d& toward_gripper,
                                    const JawGripper& gripper) {
  // the second contact: where the ray along the inward normal leaves the object (a hit from
  // inside: its normal faces inwards)
  const Eigen::Vector3d a = contact.point_mm;
  const Eigen::Vector3d inward = -contact.normal.normalized();
  const GraspScene::Hit exit =
      scene.Cast(a + 0.05 * inward, a + (gripper.max_width_mm + 1) * inward, object);
  if (!exit.hit) return std::nullopt;
  const Eigen::Vector3d b = exit.point;
  const double width = (b - a).norm();
  if (width < 0.5 || width > gripper.max_width_mm) return std::nullopt;
  const Eigen::Vector3d axis = (b - a) / width;

  // antipodal: the closing line inside both friction cones (a's inward normal is the line)
  const Eigen::Vector3d outward_b = -exit.normal;
  const double cone_deg = std::atan(gripper.friction) * 180 / M_PI;
  const double angle_b = std::acos(std::clamp(axis.dot(outward_b), -1.0, 1.0)) * 180 / M_PI;
  if (angle_b >= cone_deg) return std::nullopt;

  // the gripper comes in perpendicular to the closing line, from the viewer's side
  Eigen::Vector3d back = toward_gripper - toward_gripper.dot(axis) * axis;
  if (back.norm() < 0.2) return std::nullopt;
  back.normalize();
  JawGrasp grasp;
  grasp.point_a_mm = a;
  grasp.point_b_mm = b;
  grasp.approach = -back;
  grasp.u = contact.u;
  grasp.v = contact.v;
  grasp.width_mm = width;
  grasp.cone_margin_deg = cone_deg - angle_b;

  // room for the fingers beside each contact (three lines across each finger, outward along
  // the closing line over its thickness: anything there and it cannot close; 0 clearance), and
  // their way in (the same lines from the finger's middle back out along the approach)
  const double half = gripper.finger_width_mm / 2;
  const Eigen::Vector3d across = axis.cross(back).normalized();
  double clearance = gripper.approach_mm;
  for (const auto& [contact_point, outward] :
       {std::pair<Eigen::Vector3d, Eigen::Vector3d>{a, -axis}, {b, axis}}) {
    for (const double side : {-half, 0.0, half}) {
      const Eigen::Vector3d surface = contact_point + side * across;
      if (scene.Cast(surface + 0.5 * outward, surface + (2 * half + 1) * outward).hit) {
        clearance = 0;
        continue;
      }
      const Eigen::Vector3d from = surface + (half + 1) * outward;
      const GraspScene::Hit out = scene.Cast(from, from + gripper.approach_mm * back);
      if (out.hit) clearance = std::min(clearance, out.distance_mm);
    }
  }
  grasp.clearance_mm = clearance;
  grasp.approach_clear = clearance >= gripper.approach_mm;
  const Eigen::Vector3d lever = com_world - a;
  grasp.com_offset_mm = (lever - lever.dot(axis) * axis).norm();
  return grasp;
}

std::vector<JawGrasp> JawGrasps(const GraspScene& scene, const std::vector<SurfacePoint>& contacts,
                                int object, const Eigen::Vector3d& com_world,
                                const Eigen::Vector3d& viewer, const JawGripper& gripper) {
  std::vector<JawGrasp> grasps;
  for (const SurfacePoint& contact : contacts) {
    const Eigen::Vector3d toward = (viewer - contact.point_mm).normalized();
    if (const auto grasp = EvaluateJaw(scene, contact, object, com_world, toward, gripper)) {
      grasps.push_back(*grasp);
    }
  }
  std::sort(grasps.begin(), grasps.end(), BetterJaw);
  return grasps;
}

}  // namespace stackgen
