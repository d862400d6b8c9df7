#include "gen/physics/still_contacts.h"

#include "gen/physics/motion_bound.h"

namespace stackgen {
namespace {

// bodies marked still for the step about to run (user index 3)
constexpr int kStill = 1;
constexpr int kMoved = 0;

// the instance whose world this thread steps now: set before each step's collision search, which
// runs on the same thread right after it
thread_local StillContacts* stepping = nullptr;

bool IsStill(const btCollisionObject* object) {
  return object->isStaticObject() || object->getUserIndex3() == kStill;
}

}  // namespace

StillContacts::StillContacts(btDiscreteDynamicsWorld* world, btCollisionDispatcher* dispatcher,
                             const std::vector<btRigidBody*>& bodies, double still_distance)
    : world_(*world), dispatcher_(*dispatcher), bodies_(bodies), still_distance_(still_distance) {
  searched_at_.reserve(bodies_.size());
  radius_.reserve(bodies_.size());
  for (btRigidBody* body : bodies_) {
    searched_at_.push_back(body->getWorldTransform());
    radius_.push_back(BoundingReach(body->getCollisionShape()));
    body->setUserIndex3(kMoved);
  }
  world_.setInternalTickCallback(&StillContacts::BeforeStep, this, true);
  dispatcher_.setNearCallback(&StillContacts::NearCallback);
}

StillContacts::~StillContacts() {
  dispatcher_.setNearCallback(&btCollisionDispatcher::defaultNearCallback);
  world_.setInternalTickCallback(nullptr, nullptr, true);
  for (btRigidBody* body : bodies_) body->setUserIndex3(-1);
  if (stepping == this) stepping = nullptr;
}

void StillContacts::BeforeStep(btDynamicsWorld* world, btScalar /*time_step*/) {
  auto* self = static_cast<StillContacts*>(world->getWorldUserInfo());
  stepping = self;
  for (size_t b = 0; b < self->bodies_.size(); ++b) {
    btRigidBody* body = self->bodies_[b];
    const btTransform& now = body->getWorldTransform();
    btTransform& then = self->searched_at_[b];
    // how far any point of the body moved since its contacts were searched, at most
    const double moved = MovedAtMost(then, now, self->radius_[b]);
    if (self->first_step_ || moved > self->still_distance_) {
      then = now;
      body->setUserIndex3(kMoved);
    } else {
      body->setUserIndex3(kStill);
    }
  }
  self->first_step_ = false;
}

void StillContacts::NearCallback(btBroadphasePair& pair, btCollisionDispatcher& dispatcher,
                                 const btDispatcherInfo& info) {
  const auto* a = static_cast<const btCollisionObject*>(pair.m_pProxy0->m_clientObject);
  const auto* b = static_cast<const btCollisionObject*>(pair.m_pProxy1->m_clientObject);
  if (pair.m_algorithm == nullptr || !IsStill(a) || !IsStill(b)) {
    if (stepping != nullptr) ++stepping->searched_;
    btCollisionDispatcher::defaultNearCallback(pair, dispatcher, info);
    return;
  }
  if (stepping != nullptr) ++stepping->kept_;
  // the pair's manifolds (a compound pair has one per touching pair of pieces), refreshed as a
  // search would before adding points: positions and distances from the poses now, points that
  // separated or slid apart dropped
  btManifoldArray manifolds;
  pair.m_algorithm->getAllContactManifolds(manifolds);
  for (int m = 0; m < manifolds.size(); ++m) {
    btPersistentManifold* manifold = manifolds[m];
    if (manifold->getNumContacts() == 0) continue;
    manifold->refreshContactPoints(manifold->getBody0()->getWorldTransform(),
                                   manifold->getBody1()->getWorldTransform());
  }
}

}  // namespace stackgen
