// ConvexPairs (gen/physics/convex_pairs.h): parts of boxes and prisms tumbling into a bin and
// onto each other move the same, bit for bit, as with Bullet's own convex algorithm, while most
// queries of pairs that do not touch are skipped.
#include "gen/physics/convex_pairs.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <vector>

namespace stackgen {
namespace {

// Bullet units as the pile simulator's: cm, kg, s
constexpr btScalar kStep = 1.f / 400;
constexpr btScalar kLookAhead = 0.05f;  // 0.5 mm

// A 2 x 2 cm right triangle, 0.6 cm thick, as a hull (the connector's gusset).
void AddPrism(btConvexHullShape* hull) {
  for (float x : {-0.3f, 0.3f}) {
    hull->addPoint(btVector3(x, -1, -1), false);
    hull->addPoint(btVector3(x, 1, -1), false);
    hull->addPoint(btVector3(x, -1, 1), false);
  }
  hull->recalcLocalAabb();
}

// A cylinder 0.6 cm across and 3 cm long as a hull of 24 sides (a dowel pin).
void AddPin(btConvexHullShape* hull) {
  for (int k = 0; k < 24; ++k) {
    const float angle = static_cast<float>(k) * SIMD_2_PI / 24;
    for (float x : {-1.5f, 1.5f}) {
      hull->addPoint(btVector3(x, 0.3f * std::cos(angle), 0.3f * std::sin(angle)), false);
    }
  }
  hull->recalcLocalAabb();
}

// A static box bin (8 x 8 cm) and, dropped into it in a heap, six L-shaped parts (two plates
// as boxes and a prism in their corner, as the connector) and two loose prisms, with Bullet's
// multipoint queries (as the pile simulator sets them) and, with `paused`, ConvexPairs
// installed.
struct Tumble {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &configuration};
  std::unique_ptr<ConvexPairs> pairs;
  btBoxShape floor_shape{btVector3(5, 5, 1)};
  btBoxShape wall_x{btVector3(0.5f, 5, 4)};
  btBoxShape wall_y{btVector3(5, 0.5f, 4)};
  btCompoundShape bin;
  btConvexHullShape prism;
  btConvexHullShape pin;
  btBoxShape plate{btVector3(1.2f, 1.2f, 0.2f)};
  btBoxShape upright{btVector3(1.2f, 0.2f, 1.2f)};
  btCompoundShape part;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  explicit Tumble(bool paused, btScalar look_ahead = kLookAhead) {
    configuration.setConvexConvexMultipointIterations();
    if (paused) pairs = std::make_unique<ConvexPairs>(&dispatcher, look_ahead);
    world.setGravity(btVector3(0, 0, -981));
    AddPrism(&prism);
    AddPin(&pin);
    const btQuaternion straight = btQuaternion::getIdentity();
    bin.addChildShape(btTransform(straight, btVector3(0, 0, -1)), &floor_shape);
    bin.addChildShape(btTransform(straight, btVector3(-4.5f, 0, 4)), &wall_x);
    bin.addChildShape(btTransform(straight, btVector3(4.5f, 0, 4)), &wall_x);
    bin.addChildShape(btTransform(straight, btVector3(0, -4.5f, 4)), &wall_y);
    bin.addChildShape(btTransform(straight, btVector3(0, 4.5f, 4)), &wall_y);
    part.addChildShape(btTransform(straight, btVector3(0, 0, -1.2f)), &plate);
    part.addChildShape(btTransform(straight, btVector3(0, -1.2f, 0)), &upright);
    part.addChildShape(btTransform(straight, btVector3(0, 0, 0)), &prism);
    Add(&bin, 0, btTransform(straight, btVector3(0, 0, 0)));
    for (int i = 0; i < 6; ++i) {
      const btQuaternion turn(0.7f * i, 1.3f * i + 0.4f, 0.5f * i + 0.2f);
      Add(&part, 0.05f,
          btTransform(turn, btVector3(i % 2 ? 1.6f : -1.6f, i % 3 - 1.f, 2.5f + 2.8f * i)));
    }
    Add(&prism, 0.02f, btTransform(btQuaternion(0.3f, 0.2f, 0.1f), btVector3(0.2f, 0, 20)));
    Add(&prism, 0.02f, btTransform(btQuaternion(1.1f, -0.4f, 0.7f), btVector3(-1, 1.5f, 23)));
    for (int i = 0; i < 4; ++i) {
      Add(&pin, 0.007f,
          btTransform(btQuaternion(0.4f * i, 0.1f, 0.3f * i),
                      btVector3(i % 2 ? 1.f : -1.f, 0.8f * i - 1.2f, 26 + 2.f * i)));
    }
  }
  ~Tumble() {
    for (auto& body : bodies) world.removeRigidBody(body.get());
  }

  void Add(btCollisionShape* shape, btScalar mass, const btTransform& pose) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_startWorldTransform = pose;
    info.m_friction = 0.6f;
    bodies.push_back(std::make_unique<btRigidBody>(info));
    bodies.back()->setActivationState(DISABLE_DEACTIVATION);
    bodies.back()->setDamping(0, 0.3f);
    world.addRigidBody(bodies.back().get());
  }

  void Step() { world.stepSimulation(kStep, 0, kStep); }
};

bool SamePoses(const Tumble& a, const Tumble& b) {
  for (size_t i = 0; i < a.bodies.size(); ++i) {
    const btTransform& x = a.bodies[i]->getWorldTransform();
    const btTransform& y = b.bodies[i]->getWorldTransform();
    for (int row = 0; row < 3; ++row) {
      if (std::memcmp(&x.getBasis()[row], &y.getBasis()[row], 3 * sizeof(btScalar)) != 0) {
        return false;
      }
    }
    if (std::memcmp(&x.getOrigin(), &y.getOrigin(), 3 * sizeof(btScalar)) != 0) return false;
  }
  return true;
}

TEST(ConvexPairsTest, PartsMoveAsWithBulletsOwnSearchWhileApartPairsAreSkipped) {
  Tumble bullet(false), paused(true), close(true, 0.001f);
  int first_differs = -1;
  for (int step = 1; step <= 1600 && first_differs < 0; ++step) {  // 4 s: fall, hit, come to rest
    bullet.Step();
    paused.Step();
    close.Step();
    if (!SamePoses(bullet, paused) || !SamePoses(bullet, close)) first_differs = step;
  }
  // also with a look-ahead of 0.01 mm, where a pair is queried again as soon as a turned query
  // of Bullet's could reach it
  EXPECT_EQ(first_differs, -1) << "the poses differ from step " << first_differs;
  // the parts fell into a heap: all in the bin, none where it was dropped
  for (size_t i = 1; i < paused.bodies.size(); ++i) {
    const btVector3 at = paused.bodies[i]->getWorldTransform().getOrigin();
    EXPECT_LT(at.z(), 8) << "body " << i;
    EXPECT_LT(btMax(btFabs(at.x()), btFabs(at.y())), 4) << "body " << i;
  }
  // a good share of the queries were skipped: pairs whose boxes overlap but which do not touch
  EXPECT_GT(paused.pairs->searched(), 1000);
  EXPECT_GT(paused.pairs->paused(), paused.pairs->searched() / 4);
}

TEST(ConvexPairsTest, ALookAheadThatIsNotPositiveIsRefused) {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher(&configuration);
  EXPECT_THROW(ConvexPairs(&dispatcher, 0), std::invalid_argument);
}

}  // namespace
}  // namespace stackgen
