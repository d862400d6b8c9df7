#pragma once

#include <vector>

#include <btBulletDynamicsCommon.h>

namespace stackgen {

/// Keeps the contacts of parts that lie still instead of searching them again every step: a pile
/// at rest spends most of its steps finding the same contact points between parts that have not
/// moved. While installed on a world, before each step every body whose points all moved less
/// than `still_distance` (Bullet units; the centre of mass's move plus its bounding radius times
/// the turn) since its contacts were last searched counts as still; a pair of still bodies (a
/// static body is always still) keeps its contact points, refreshed to the bodies' poses now
/// (distances, positions, points that separated dropped), and every other pair is searched as
/// Bullet does. A body that moved further is searched again with all its pairs, and its poses
/// count from there. Bodies are still simulated every step: gravity, contacts and friction act
/// on them as before, so a part that starts to slide or tip is searched again within a step of
/// moving `still_distance`. The same inputs give the same steps, bit for bit.
///
/// It uses the world's pre-tick callback and its dispatcher's near callback and the bodies' user
/// index 3; the destructor puts Bullet's own back. The world and bodies must outlive it.
class StillContacts {
 public:
  StillContacts(btDiscreteDynamicsWorld* world, btCollisionDispatcher* dispatcher,
                const std::vector<btRigidBody*>& bodies, double still_distance);
  ~StillContacts();
  StillContacts(const StillContacts&) = delete;
  StillContacts& operator=(const StillContacts&) = delete;

  /// Pairs whose contacts were kept, and searched, since the start.
  long kept() const { return kept_; }
  long searched() const { return searched_; }

 private:
  static void BeforeStep(btDynamicsWorld* world, btScalar time_step);
  static void NearCallback(btBroadphasePair& pair, btCollisionDispatcher& dispatcher,
                           const btDispatcherInfo& info);

  btDiscreteDynamicsWorld& world_;
  btCollisionDispatcher& dispatcher_;
  std::vector<btRigidBody*> bodies_;
  std::vector<btTransform> searched_at_;  // each body's pose when its contacts were searched
  std::vector<double> radius_;            // each body's points' largest distance from its centre
  double still_distance_;
  bool first_step_ = true;
  long kept_ = 0;
  long searched_ = 0;
};

}  // namespace stackgen
