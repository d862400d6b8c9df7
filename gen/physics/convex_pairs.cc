#include "gen/physics/convex_pairs.h"

#include <BulletCollision/CollisionDispatch/btConvexConvexAlgorithm.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkPairDetector.h>
#include <BulletCollision/NarrowPhaseCollision/btPointCollector.h>
#include <BulletCollision/NarrowPhaseCollision/btVoronoiSimplexSolver.h>

#include <memory>
#include <new>
#include <stdexcept>
#include <string>

#include "gen/physics/motion_bound.h"

namespace stackgen {
namespace {

// Bullet's multipoint setting: 3 turned queries while the manifold holds fewer than 3 points
constexpr int kTurnedQueries = 3;
constexpr int kFewPoints = 3;

// Bullet's convex algorithm for a pair, on the pair's manifold, skipped while the pair is apart
// (ConvexPairs).
class PausedPair : public btActivatingCollisionAlgorithm {
 public:
  PausedPair(const btCollisionAlgorithmConstructionInfo& info, const btCollisionObjectWrapper* a,
             const btCollisionObjectWrapper* b, btConvexPenetrationDepthSolver* depth_solver,
             btScalar look_ahead, long* paused, long* searched)
      : btActivatingCollisionAlgorithm(info, a, b),
        manifold_(info.m_manifold),
        depth_solver_(depth_solver),
        look_ahead_(look_ahead),
        paused_(paused),
        searched_(searched),
        shape_a_(a->getCollisionShape()),
        shape_b_(b->getCollisionShape()),
        reach_a_(BoundingReach(shape_a_)),
        reach_b_(BoundingReach(shape_b_)) {}

  ~PausedPair() override {
    inner_.reset();
    if (own_manifold_) m_dispatcher->releaseManifold(manifold_);
  }

  void processCollision(const btCollisionObjectWrapper* a, const btCollisionObjectWrapper* b,
                        const btDispatcherInfo& dispatch, btManifoldResult* out) override {
    // the manifold at the first query, as Bullet's algorithm makes it (the order in which
    // manifolds are made is the order the solver meets their contacts in)
    if (inner_ == nullptr) {
      if (manifold_ == nullptr) {
        manifold_ = m_dispatcher->getNewManifold(a->getCollisionObject(), b->getCollisionObject());
        own_manifold_ = true;
      }
      btCollisionAlgorithmConstructionInfo info(m_dispatcher, 0);
      inner_ = std::make_unique<btConvexConvexAlgorithm>(manifold_, info, a, b, depth_solver_,
                                                         kTurnedQueries, kFewPoints);
    }
    out->setPersistentManifold(manifold_);
    const bool touching = manifold_->getNumContacts() > 0;
    if (!touching && apart_ && a->getCollisionShape() == shape_a_ &&
        b->getCollisionShape() == shape_b_ &&
        MovedAtMost(a_at_, a->getWorldTransform(), reach_a_) +
                MovedAtMost(b_at_, b->getWorldTransform(), reach_b_) <
            look_ahead_ / 2) {
      ++*paused_;
      return;  // still apart: nothing to find, no points to refresh
    }
    ++*searched_;
    if (!touching) {
      apart_ = Apart(a, b);
      if (apart_) {
        a_at_ = a->getWorldTransform();
        b_at_ = b->getWorldTransform();
        return;
      }
    }
    apart_ = false;
    inner_->processCollision(a, b, dispatch, out);
    if (own_manifold_) out->refreshContactPoints();
  }

  btScalar calculateTimeOfImpact(btCollisionObject* a, btCollisionObject* b,
                                 const btDispatcherInfo& dispatch, btManifoldResult* out) override {
    return inner_ == nullptr ? btScalar(1) : inner_->calculateTimeOfImpact(a, b, dispatch, out);
  }

  void getAllContactManifolds(btManifoldArray& manifolds) override {
    if (own_manifold_ && manifold_ != nullptr) manifolds.push_back(manifold_);
  }

 private:
  // Whether no query of Bullet's could find a point now, and none until the pieces moved
  // look_ahead_ / 2: GJK stops without a result once it has proved the distance of the pieces'
  // cores (margins left out) beyond `reach`. Bullet's GJK finds a point within the contact
  // threshold of the pieces grown by their margins, and each turned query turns one piece by
  // gContactBreakingThreshold over its bounding radius, which moves its points less than
  // gContactBreakingThreshold, and the point found (moved back) by as much again.
  bool Apart(const btCollisionObjectWrapper* a, const btCollisionObjectWrapper* b) const {
    const auto* convex_a = static_cast<const btConvexShape*>(a->getCollisionShape());
    const auto* convex_b = static_cast<const btConvexShape*>(b->getCollisionShape());
    const btScalar reach = convex_a->getMargin() + convex_b->getMargin() +
                           manifold_->getContactBreakingThreshold() +
                           2 * gContactBreakingThreshold + look_ahead_;
    btVoronoiSimplexSolver simplex;
    btGjkPairDetector gjk(convex_a, convex_b, &simplex, depth_solver_);
    btGjkPairDetector::ClosestPointInput input;
    input.m_maximumDistanceSquared = reach * reach;
    input.m_transformA = a->getWorldTransform();
    input.m_transformB = b->getWorldTransform();
    btPointCollector found;
    gjk.getClosestPoints(input, found, nullptr);
    return !found.m_hasResult;
  }

  bool own_manifold_ = false;
  btPersistentManifold* manifold_;
  // Bullet's convex algorithm on manifold_, with its turned queries
  std::unique_ptr<btConvexConvexAlgorithm> inner_;
  btConvexPenetrationDepthSolver* const depth_solver_;
  const btScalar look_ahead_;
  long* const paused_;
  long* const searched_;
  const btCollisionShape* const shape_a_;
  const btCollisionShape* const shape_b_;
  const double reach_a_;
  const double reach_b_;
  // found apart, and the pieces' poses then
  bool apart_ = false;
  btTransform a_at_;
  btTransform b_at_;
};

}  // namespace

btCollisionAlgorithm* ConvexPairs::CreateFunc::CreateCollisionAlgorithm(
    btCollisionAlgorithmConstructionInfo& info, const btCollisionObjectWrapper* a,
    const btCollisionObjectWrapper* b) {
  // outside the dispatcher's pool, whose blocks may be smaller (freeCollisionAlgorithm frees
  // either)
  void* memory = btAlignedAlloc(sizeof(PausedPair), 16);
  return new (memory) PausedPair(info, a, b, depth_solver, look_ahead, &paused, &searched);
}

ConvexPairs::ConvexPairs(btCollisionDispatcher* dispatcher, btScalar look_ahead) {
  if (!(look_ahead > 0)) {
    throw std::invalid_argument("ConvexPairs: look_ahead must be > 0, got " +
                                std::to_string(look_ahead));
  }
  create_.look_ahead = look_ahead;
  create_.depth_solver = &depth_solver_;
  dispatcher->registerCollisionCreateFunc(CONVEX_HULL_SHAPE_PROXYTYPE, CONVEX_HULL_SHAPE_PROXYTYPE,
                                          &create_);
  dispatcher->registerCollisionCreateFunc(CONVEX_HULL_SHAPE_PROXYTYPE, BOX_SHAPE_PROXYTYPE,
                                          &create_);
  dispatcher->registerCollisionCreateFunc(BOX_SHAPE_PROXYTYPE, CONVEX_HULL_SHAPE_PROXYTYPE,
                                          &create_);
}

}  // namespace stackgen
