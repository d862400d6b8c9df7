#pragma once

#include <btBulletDynamicsCommon.h>

#include <BulletCollision/NarrowPhaseCollision/btGjkEpaPenetrationDepthSolver.h>

namespace stackgen {

/// The contact search of convex pieces that are not both boxes (a part's hull pieces against
/// anything; box against box keeps Bullet's box-box test), skipping pairs found apart, installed
/// on a dispatcher. Where two parts' boxes overlap, Bullet searches every pair of their pieces
/// whose boxes overlap, every step, and most such pairs do not touch. Each pair here runs
/// Bullet's own algorithm (GJK with 3 turned queries while the manifold holds fewer than 3
/// points, as btDefaultCollisionConfiguration::setConvexConvexMultipointIterations() sets),
/// except while it is apart: a pair with no contact point whose pieces GJK proves further apart
/// than any of Bullet's queries could find a point at, plus `look_ahead`, is not searched again
/// until its pieces may have moved look_ahead / 2 (a bound on how far any of their points moved:
/// each piece's move plus its turn times the radius of a sphere around it). So it finds the
/// points Bullet finds, and the piles are the same to the last bit; it only saves the queries.
/// The dispatcher and the pieces' shapes must outlive the algorithms it makes; not copyable.
class ConvexPairs {
 public:
  /// Registers the algorithm for hull-hull, hull-box and box-hull pairs; look_ahead in Bullet's
  /// units. Throws std::invalid_argument unless look_ahead > 0.
  ConvexPairs(btCollisionDispatcher* dispatcher, btScalar look_ahead);
  ConvexPairs(const ConvexPairs&) = delete;
  ConvexPairs& operator=(const ConvexPairs&) = delete;

  /// Pair queries since the start: skipped while apart, and run (Bullet's algorithm or the
  /// GJK query that found the pair apart).
  long paused() const { return create_.paused; }
  long searched() const { return create_.searched; }

 private:
  struct CreateFunc : public btCollisionAlgorithmCreateFunc {
    btCollisionAlgorithm* CreateCollisionAlgorithm(btCollisionAlgorithmConstructionInfo& info,
                                                   const btCollisionObjectWrapper* a,
                                                   const btCollisionObjectWrapper* b) override;
    btConvexPenetrationDepthSolver* depth_solver = nullptr;
    btScalar look_ahead = 0;
    long paused = 0;
    long searched = 0;
  };
  btGjkEpaPenetrationDepthSolver depth_solver_;
  CreateFunc create_;
};

}  // namespace stackgen
