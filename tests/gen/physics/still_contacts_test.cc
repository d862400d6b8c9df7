// StillContacts (gen/physics/still_contacts.h): a box lying still on a floor keeps its contacts
// instead of searching them every step, and stays where it lies; pushed, it is searched again
// and slides to where Bullet's own search every step brings it, without sinking into the floor.
#include "gen/physics/still_contacts.h"

#include <gtest/gtest.h>

#include <memory>
#include <vector>

namespace stackgen {
namespace {

// Bullet units as the pile simulator's: cm, kg, s
constexpr btScalar kStep = 1.f / 300;
constexpr double kStillDistance = 0.0005;  // 5 micrometres

// A static floor and a 4 x 4 x 2 cm box of 100 g lying on it.
struct FloorAndBox {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &configuration};
  btBoxShape floor_shape{btVector3(50, 50, 5)};
  btBoxShape box_shape{btVector3(2, 2, 1)};
  std::unique_ptr<btRigidBody> floor;
  std::unique_ptr<btRigidBody> box;

  FloorAndBox() {
    world.setGravity(btVector3(0, 0, -981));
    btRigidBody::btRigidBodyConstructionInfo floor_info(0, nullptr, &floor_shape);
    floor_info.m_startWorldTransform.setOrigin(btVector3(0, 0, -5));
    floor_info.m_friction = 0.7f;
    floor = std::make_unique<btRigidBody>(floor_info);
    world.addRigidBody(floor.get());
    btVector3 inertia;
    box_shape.calculateLocalInertia(0.1f, inertia);
    btRigidBody::btRigidBodyConstructionInfo box_info(0.1f, nullptr, &box_shape, inertia);
    box_info.m_startWorldTransform.setOrigin(btVector3(0, 0, 1.02f));
    box_info.m_friction = 0.7f;
    box = std::make_unique<btRigidBody>(box_info);
    box->setActivationState(DISABLE_DEACTIVATION);
    world.addRigidBody(box.get());
  }
  ~FloorAndBox() {
    world.removeRigidBody(box.get());
    world.removeRigidBody(floor.get());
  }

  void Run(double seconds) {
    for (int i = 0; i < static_cast<int>(seconds / kStep + 0.5); ++i) {
      world.stepSimulation(kStep, 0, kStep);
    }
  }
  btVector3 Position() const { return box->getWorldTransform().getOrigin(); }
};

TEST(StillContactsTest, AStillBoxKeepsItsContactsAndAPushedOneIsSearchedAgain) {
  FloorAndBox kept, searched;
  kept.Run(1);
  searched.Run(1);
  const btVector3 lying = kept.Position();
  ASSERT_NEAR(lying.z(), 1, 0.01);

  StillContacts still(&kept.world, &kept.dispatcher, {kept.box.get()}, kStillDistance);
  kept.Run(1);
  searched.Run(1);
  // lying still, its pair with the floor is kept on (nearly) every step, and it stays put
  EXPECT_GE(still.kept(), 290);
  EXPECT_LE(still.searched(), 10);
  EXPECT_LT((kept.Position() - lying).length(), 1e-4);

  // pushed along the floor at 30 cm/s, it slides about 0.6 cm and stops where the box whose
  // contacts are searched every step stops, at the same height: the floor still holds it
  const long searched_before = still.searched();
  kept.box->setLinearVelocity(btVector3(30, 0, 0));
  searched.box->setLinearVelocity(btVector3(30, 0, 0));
  kept.Run(1);
  searched.Run(1);
  EXPECT_GT(still.searched() - searched_before, 10);
  EXPECT_GT(kept.Position().x() - lying.x(), 0.3);
  EXPECT_LT((kept.Position() - searched.Position()).length(), 0.005);
  EXPECT_NEAR(kept.Position().z(), searched.Position().z(), 0.001);
}

// The callbacks are Bullet's own again once it is gone.
TEST(StillContactsTest, GoneItLeavesBulletsOwnCallbacks) {
  FloorAndBox world;
  {
    StillContacts still(&world.world, &world.dispatcher, {world.box.get()}, kStillDistance);
    world.Run(0.1);
  }
  EXPECT_EQ(world.dispatcher.getNearCallback(), &btCollisionDispatcher::defaultNearCallback);
  EXPECT_EQ(world.world.getWorldUserInfo(), nullptr);
  EXPECT_EQ(world.box->getUserIndex3(), -1);
}

}  // namespace
}  // namespace stackgen
