#pragma once

// What the pile simulator's own files share (pile.cc, pile_release.cc, pile_types.cc): the part
// types ready to simulate, the queue that releases parts above the bin, and a few constants. Not
// for use outside gen/physics/.

#include <cmath>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "gen/physics/hull_faces.h"
#include "gen/physics/mass_properties.h"
#include "gen/physics/pile.h"

namespace stackgen {
namespace pile_internal {

// collision margin of the part pieces and the bin, mm; hull pieces are shrunk by it first, so
// the rounded shape Bullet collides has the mesh's size
inline constexpr double kMarginMm = 0.2;

// released parts: gap between their bounding boxes, and to the walls, mm
inline constexpr double kReleaseGapMm = 2;
inline constexpr double kReleaseWallMarginMm = 2;

// after this long without a release, the first waiting part goes above whatever blocks it, s
inline constexpr double kStallS = 0.5;

// Throws unless lo <= value <= hi.
void CheckRange(const char* object, const char* field, double value, double lo, double hi);

// Throws, naming the field, unless the bin's and the simulation's values are in range.
void CheckInputs(const BinSpec& bin, const SimulationParams& params);

// An axis-aligned box, mm.
struct Box {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL);
  Eigen::Vector3d hi = Eigen::Vector3d::Constant(-HUGE_VAL);

  void Add(const Eigen::Vector3d& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  // true if the boxes come closer than `gap`
  bool Overlaps(const Box& other, double gap) const {
    for (int axis = 0; axis < 3; ++axis) {
      if (hi[axis] + gap <= other.lo[axis] || other.hi[axis] + gap <= lo[axis]) return false;
    }
    return true;
  }
};

// How one part is dropped, drawn up front from the seed's engine.
struct Release {
  int type = 0;
  Eigen::Quaterniond world_from_object_rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d object_origin_in_box_mm = Eigen::Vector3d::Zero();  // from the box's low corner
  Eigen::Vector3d size_mm = Eigen::Vector3d::Zero();                  // rotated bounding box
  Eigen::Vector2d box_lo_xy_mm = Eigen::Vector2d::Zero();             // its low corner, x and y

  Box BoxAt(double z_mm) const {
    Box box;
    box.lo = Eigen::Vector3d(box_lo_xy_mm.x(), box_lo_xy_mm.y(), z_mm);
    box.hi = box.lo + size_mm;
    return box;
  }
  Eigen::Isometry3d WorldFromObjectAt(double z_mm) const {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = world_from_object_rotation.toRotationMatrix();
    pose.translation() = BoxAt(z_mm).lo + object_origin_in_box_mm;
    return pose;
  }
};

// Parts waiting above the bin, released in quick waves so none falls far: a part goes when its
// box at the release height is free; one blocked only by parts resting in the pile (a pile
// higher than the release height) goes just above them; after kStallS without any release the
// first waiting part goes above whatever blocks it.
//
// Sequential: only the first waiting part may go, and only once the previous one has landed; it
// goes at the release height, or just above whatever is there.
class ReleaseQueue {
 public:
  ReleaseQueue(std::vector<Release> releases, double release_z_mm, bool sequential)
      : releases_(std::move(releases)), release_z_mm_(release_z_mm), sequential_(sequential) {
    for (size_t i = 0; i < releases_.size(); ++i) waiting_.push_back(static_cast<int>(i));
  }

  bool empty() const { return waiting_.empty(); }
  const Release& release(int part) const { return releases_[part]; }
  double release_z_mm() const { return release_z_mm_; }

  // Given the boxes of the bodies in the bin, whether each rests in the pile and whether the last
  // released part has landed, returns the parts to release now with the height of their boxes'
  // bottoms.
  std::vector<std::pair<int, double>> Next(double time_s, std::vector<Box> boxes,
                                           const std::vector<bool>& in_pile, bool landed);

 private:
  std::vector<Release> releases_;
  double release_z_mm_;
  bool sequential_;
  std::vector<int> waiting_;
  double last_release_s_ = 0;
};

// One convex piece of the part, ready to become a Bullet shape.
struct Piece {
  bool is_box = false;
  Eigen::Vector3d half_extents_mm = Eigen::Vector3d::Zero();          // boxes (margin inside)
  Eigen::Isometry3d body_from_piece = Eigen::Isometry3d::Identity();  // mm
  std::vector<Eigen::Vector3d> points_mm;  // hulls: body frame, shrunk by margin_mm
  double margin_mm = kMarginMm;
};

// One part type, ready to simulate.
struct TypeModel {
  PartPhysics physics;
  MassProperties mass;
  // the body frame: at the centre of mass, along the principal axes of inertia; mm
  Eigen::Isometry3d body_from_object = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d object_from_body = Eigen::Isometry3d::Identity();
  std::vector<Piece> pieces;
  std::vector<Eigen::Vector3d> hull_vertices_mm;  // object frame, for release boxes
  std::vector<HullFace> hull_faces;
  double max_extent_mm = 0;
  std::string description;
};

// Builds a part type; errors start with `what`.
TypeModel MakeTypeModel(const PartType& type, const std::string& what,
                        const std::string& cache_dir);

// How each part of `types` drops, all drawn now from `engine`: orientation, bounding box, and
// x, y inside the opening (pile_release.cc).
std::vector<Release> DrawReleases(const std::vector<TypeModel>& type_models,
                                  const std::vector<int>& types, const BinSpec& bin,
                                  const SimulationParams& params, std::mt19937_64& engine);

}  // namespace pile_internal
}  // namespace stackgen
