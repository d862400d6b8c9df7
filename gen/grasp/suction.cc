#include "gen/grasp/suction.h"

#include <algorithm>
#include <cmath>
#include <tuple>

namespace stackgen {

bool BetterSuction(const SuctionGrasp& a, const SuctionGrasp& b) {
  return std::make_tuple(!a.approach_clear, -a.seal, a.com_offset_mm, a.v, a.u) <
         std::make_tuple(!b.approach_clear, -b.seal, b.com_offset_mm, b.v, b.u);
}

SuctionGrasp EvaluateSuction(const GraspScene& scene, const Eigen::Vector3d& point,
                             const Eigen::Vector3d& normal, int object,
                             const Eigen::Vector3d& com_world, const SuctionCup& cup) {
  SuctionGrasp grasp;
  grasp.point_mm = point;
  grasp.normal = normal.normalized();
  const Eigen::Vector3d& n = grasp.normal;
  const auto [t1, t2] = TangentsOf(n);

  // the seal: the part's surface under the cup's disc (centre, half radius, lip) within the
  // lip's compliance of the tangent plane, each point looked for from above
  const double radius = cup.diameter_mm / 2;
  const double reach = cup.compliance_mm + 5;
  int sealed = 0, samples = 0;
  for (const auto& [ring_radius, count] : {std::pair<double, int>{0, 1}, {radius / 2, 8},
                                           {radius, 16}}) {
    for (int k = 0; k < count; ++k) {
      const double angle = 2 * M_PI * k / count;
      const Eigen::Vector3d q =
          point + ring_radius * (std::cos(angle) * t1 + std::sin(angle) * t2);
      const GraspScene::Hit below = scene.Cast(q + reach * n, q - reach * n, object);
      ++samples;
      if (below.hit && std::abs((below.point - point).dot(n)) <= cup.compliance_mm) ++sealed;
    }
  }
  grasp.seal = static_cast<double>(sealed) / samples;

  // the approach: the tool's cylinder (its axis and 16 lines on its side) out along the normal,
  // from just above the lip's compliance, against everything
  const double start = cup.compliance_mm + 1;
  double clearance = cup.approach_mm;
  const double tool_radius = std::max(cup.tool_diameter_mm, cup.diameter_mm) / 2;
  for (int k = -1; k < 16; ++k) {
    const double angle = 2 * M_PI * k / 16;
    const Eigen::Vector3d q =
        point + start * n +
        (k < 0 ? Eigen::Vector3d::Zero()
               : Eigen::Vector3d(tool_radius * (std::cos(angle) * t1 + std::sin(angle) * t2)));
    const GraspScene::Hit out = scene.Cast(q, q + (cup.approach_mm - start) * n);
    if (out.hit) clearance = std::min(clearance, start + out.distance_mm);
  }
  grasp.clearance_mm = clearance;
  grasp.approach_clear = clearance >= cup.approach_mm;
  const Eigen::Vector3d lever = com_world - point;
  grasp.com_offset_mm = (lever - lever.dot(n) * n).norm();
  return grasp;
}

std::vector<SuctionGrasp> SuctionGrasps(const GraspScene& scene,
                                        const std::vector<SurfacePoint>& contacts, int object,
                                        const Eigen::Vector3d& com_world, const SuctionCup& cup) {
  std::vector<SuctionGrasp> grasps;
  for (const SurfacePoint& contact : contacts) {
    SuctionGrasp grasp =
        EvaluateSuction(scene, contact.point_mm, contact.normal, object, com_world, cup);
    grasp.u = contact.u;
    grasp.v = contact.v;
    grasps.push_back(grasp);
  }
  std::sort(grasps.begin(), grasps.end(), BetterSuction);
  return grasps;
}

}  // namespace stackgen
