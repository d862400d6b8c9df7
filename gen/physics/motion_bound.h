#pragma once

#include <algorithm>
#include <cmath>

#include <btBulletDynamicsCommon.h>

namespace stackgen {

/// The radius about a shape's origin of a sphere around it, margin included.
inline double BoundingReach(const btCollisionShape* shape) {
  btVector3 centre;
  btScalar radius = 0;
  shape->getBoundingSphere(centre, radius);
  return centre.length() + radius;
}

/// A bound on how far any point within `reach` of a frame's origin moved from `then` to `now`:
/// the origin's move plus the reach times the angle it turned.
inline double MovedAtMost(const btTransform& then, const btTransform& now, double reach) {
  const btQuaternion turn = then.getRotation().inverse() * now.getRotation();
  const double sine = std::min<double>(1, btVector3(turn.x(), turn.y(), turn.z()).length());
  return (now.getOrigin() - then.getOrigin()).length() + reach * 2 * std::asin(sine);
}

}  // namespace stackgen
