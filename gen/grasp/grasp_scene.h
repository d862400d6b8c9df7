#pragma once

// The meshes of one scene for grasp rays, and the surface points grasps start from.
//
// The scene's meshes are held as Bullet triangle meshes with bounding-volume trees (Bullet's
// btBvhTriangleMeshShape), at their poses, and every question a grasp asks is a ray: from the
// camera through a pixel to the surface it shows (a contact and its exact face normal), straight
// down onto a part (a contact seen from above), and then whatever the kind of grasp asks
// (suction.h, parallel_jaw.h). Millimetres, world frame.

#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "gen/mesh/mesh.h"
#include "gen/render/renderer.h"

namespace stackgen {

/// A point on an object's surface where a grasp may start.
struct SurfacePoint {
  Eigen::Vector3d point_mm{0, 0, 0};  // world frame
  Eigen::Vector3d normal{0, 0, 1};    // the face's outward unit normal (towards the viewer)
  int u = -1, v = -1;                 // the pixel (or grid cell, seen from above) it was found at
};

/// Two unit vectors that make a right-handed frame (t1, t2, n) with the unit `n`.
std::pair<Eigen::Vector3d, Eigen::Vector3d> TangentsOf(const Eigen::Vector3d& n);

/// The meshes of one scene, for rays. Not thread-safe; cheap to fill per scene (the trees of the
/// meshes are built once, by AddMesh).
class GraspScene {
 public:
  GraspScene();
  ~GraspScene();
  GraspScene(const GraspScene&) = delete;
  GraspScene& operator=(const GraspScene&) = delete;

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

  /// Up to `count` points of object `object` as `camera` sees it: pixels spread over its pixels
  /// in `instance_map` (CV_16UC1) whose value is `instance_id` (farthest point sampling over the
  /// inner half of its region, by distance to the region's edge, from its deepest pixel), each
  /// the surface the camera's ray through that pixel's centre hits. A pixel whose ray meets
  /// another object first (the map's pixel centre and the mesh disagree by a hair at an edge) is
  /// skipped.
  std::vector<SurfacePoint> SeenPoints(const CameraModel& camera, const cv::Mat& instance_map,
                                       int instance_id, int object, int count) const;

  /// As SeenPoints, seen straight down instead of by a camera (a robot picking from above):
  /// vertical rays on a grid of pitch_mm over the object's box, the cells where the object is
  /// met first standing for its pixels (u, v: the cell). Empty when the object is not placed or
  /// nothing of it is seen from above.
  std::vector<SurfacePoint> PointsFromAbove(int object, int count, double pitch_mm = 2) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
