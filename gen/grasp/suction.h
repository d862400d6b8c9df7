#pragma once

// Suction grasps on the visible parts of a scene: where a cup can go, how well it seals, and
// whether the tool can come in along the surface's normal.
//
// The scene's meshes are held as Bullet triangle meshes with bounding-volume trees (Bullet's
// btBvhTriangleMeshShape), at their poses, and every question is a ray: from the camera through
// a pixel to the surface it shows (the contact and its exact face normal), down onto the part
// over the cup's disc (the seal), and out along the normal (the approach). Millimetres, world
// frame. The seal follows Dex-Net 3.0 (Mahler et al. 2018) in spirit: a cup of a given diameter
// seals where the part's surface under its whole disc lies within the lip's compliance of the
// tangent plane at the contact; a hole under the disc, an edge it hangs over or a curved face
// breaks the seal.

#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "gen/mesh/mesh.h"
#include "gen/render/renderer.h"

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
  int u = 0, v = 0;                   // the pixel the contact was seen in
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

/// The meshes of one scene, for rays. Not thread-safe; cheap to build per scene (the trees of
/// the meshes are built once, by AddMesh).
class SuctionScene {
 public:
  SuctionScene();
  ~SuctionScene();
  SuctionScene(const SuctionScene&) = delete;
  SuctionScene& operator=(const SuctionScene&) = delete;

  /// A mesh (mm, its own frame) rays can hit; returns its mesh id (0, 1, ...). Throws
  /// std::invalid_argument for a mesh without triangles or with an index out of range.
  int AddMesh(const TriangleMesh& mesh);
  /// Places a copy of a mesh; `object` names it in hits (>= 1 for parts, 0 for the bin and the
  /// rest of the scenery). Throws std::invalid_argument for an unknown mesh id.
  void AddObject(int mesh_id, const Eigen::Isometry3d& world_from_object, int object);
  /// Removes every placed object (the meshes stay).
  void ClearObjects();

  /// The first surface on the segment from `from` to `to` (world, mm): whether there is one,
  /// its point, its face normal turned towards `from`, its object and its distance from `from`.
  /// With only_object >= 0, only that object is hit.
  struct Hit {
    bool hit = false;
    Eigen::Vector3d point{0, 0, 0};
    Eigen::Vector3d normal{0, 0, 1};
    int object = -1;
    double distance_mm = 0;
  };
  Hit Cast(const Eigen::Vector3d& from, const Eigen::Vector3d& to, int only_object = -1) const;

  /// A grasp at `point` on `object` with outward `normal` (world, mm), evaluated for `cup`: its
  /// seal on that object, its clearance against everything, and its lever about `com_world`.
  SuctionGrasp Evaluate(const Eigen::Vector3d& point, const Eigen::Vector3d& normal, int object,
                        const Eigen::Vector3d& com_world, const SuctionCup& cup) const;

  /// The grasps of object `object` as `camera` sees it: up to cup.candidates_per_part contacts
  /// spread over its pixels in `instance_map` (CV_16UC1) whose value is `instance_id` (farthest
  /// point sampling in the image, from the pixel nearest the pixels' centroid), each the
  /// surface the camera's ray through that pixel's centre hits on the object, evaluated and
  /// ordered best first (BetterSuction). Contacts whose ray meets another object first (the
  /// map's pixel centre and the mesh disagree by a hair at an edge) are skipped.
  std::vector<SuctionGrasp> Candidates(const CameraModel& camera, const cv::Mat& instance_map,
                                       int instance_id, int object,
                                       const Eigen::Vector3d& com_world,
                                       const SuctionCup& cup) const;

  /// As Candidates, seen straight down instead of by a camera (a robot picking from above):
  /// vertical rays on a grid of pitch_mm over the object's box, the cells where the object is
  /// met first standing for its pixels; u and v are the grid cell. Empty when the object is not
  /// placed or nothing of it is seen from above.
  std::vector<SuctionGrasp> CandidatesFromAbove(int object, const Eigen::Vector3d& com_world,
                                                const SuctionCup& cup, double pitch_mm = 2) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
