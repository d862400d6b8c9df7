#pragma once

// Suction grasps: where a cup can go on a part, how well it seals, and whether the tool can
// come in along the surface's normal, all by rays against the scene's meshes (GraspScene). The
// seal follows Dex-Net 3.0 (Mahler et al. 2018) in spirit: a cup of a given diameter seals where
// the part's surface under its whole disc lies within the lip's compliance of the tangent plane
// at the contact; a hole under the disc, an edge it hangs over or a curved face breaks the seal.

#include <vector>

#include <Eigen/Core>

#include "gen/grasp/grasp_scene.h"

namespace stackgen {

/// The suction cup and how candidates are chosen (config GraspConfig).
struct SuctionCup {
  double diameter_mm = 15;       // the lip's outer diameter, > 0
  double compliance_mm = 1.5;    // how far the lip gives: the seal's tolerance, > 0
  double approach_mm = 150;      // the tool's clear length along the normal, > 0
  double tool_diameter_mm = 20;  // the tool's diameter over that length, >= diameter_mm
  int candidates_per_part = 8;   // contacts tried on each visible part, >= 1
};

/// One evaluated suction grasp.
struct SuctionGrasp {
  Eigen::Vector3d point_mm{0, 0, 0};  // the contact, world frame
  Eigen::Vector3d normal{0, 0, 1};    // the surface's outward unit normal: the cup approaches
                                      // along -normal
  int u = 0, v = 0;                   // the pixel (or grid cell) the contact was found at
  /// Fraction (0..1) of the cup's disc (its centre, 8 points at half the radius and 16 on the
  /// lip) under which the part's surface lies within compliance_mm of the contact's tangent
  /// plane: 1 a full seal, less where the disc hangs over an edge, a hole or a curve.
  double seal = 0;
  /// Distance along the normal to the first thing (another part, the bin, the part itself) the
  /// tool's cylinder would meet, mm; approach_mm when nothing within it.
  double clearance_mm = 0;
  bool approach_clear = false;  // clearance_mm >= approach_mm
  /// Distance of the part's centre of mass from the approach axis, mm: the lever of gravity
  /// about the cup (Dex-Net's wrench resistance falls as it grows).
  double com_offset_mm = 0;
};

/// Orders grasps best first: approach clear before blocked, then higher seal, then smaller
/// com_offset_mm, then pixel (v, u) (a total order: the same on every run).
bool BetterSuction(const SuctionGrasp& a, const SuctionGrasp& b);

/// A grasp at `point` on `object` with outward `normal` (world, mm), evaluated for `cup`: its
/// seal on that object, its clearance against everything in `scene`, and its lever about
/// `com_world`.
SuctionGrasp EvaluateSuction(const GraspScene& scene, const Eigen::Vector3d& point,
                             const Eigen::Vector3d& normal, int object,
                             const Eigen::Vector3d& com_world, const SuctionCup& cup);

/// The grasps at `contacts` (GraspScene::SeenPoints or PointsFromAbove of `object`), evaluated
/// and ordered best first (BetterSuction); each keeps its contact's u, v.
std::vector<SuctionGrasp> SuctionGrasps(const GraspScene& scene,
                                        const std::vector<SurfacePoint>& contacts, int object,
                                        const Eigen::Vector3d& com_world, const SuctionCup& cup);

}  // namespace stackgen
