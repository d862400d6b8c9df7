#include "gen/physics/pile.h"

#include <LinearMath/btConvexHullComputer.h>
#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "gen/physics/convex_pairs.h"
#include "gen/physics/pile_internal.h"
#include "gen/physics/settle_detector.h"
#include "gen/physics/still_contacts.h"

namespace stackgen {

using namespace pile_internal;

namespace {

// Bullet runs in centimetres (and kg, s): millimetre parts would sit below Bullet's built-in
// tolerances (contact breaking 0.02 units, default margin 0.04 units), metres above them
constexpr double kSimPerMm = 0.1;
constexpr double kGravityMmS2 = 9810.0;
// how far beyond any contact a hull piece and another piece must lie apart for the search of
// the pair to pause (ConvexPairs), mm
constexpr double kConvexLookAheadMm = 0.5;
// Lift: the contacts take up the load for this long before the hold pulls, and it holds
// the part this long at the top, s
constexpr double kLiftSettleS = 0.1;
constexpr double kLiftHoldS = 0.3;

// contact solver: each step starts from this share of the last step's impulses, and impacts
// slower than this (mm/s) do not bounce. With Bullet's 0.85 a resting pile's impulses never
// converged and heaps crept on for tens of seconds; the whole impulse converges
constexpr double kWarmStartingFactor = 1;
constexpr double kRestitutionThresholdMmS = 50;

// A pile in two phases. Falling: split-impulse contacts (overlap is undone by moving the parts
// apart, which adds no energy to an impact) at time_step_s, and with
// free_friction_while_falling Bullet's own friction (along the sliding velocity, at most
// kDropIterations iterations), so a flat box landing on its edge topples flat as a real one does.
// Once it has landed (kPileLanded*, or the settle rule where looser): friction that holds it
// (two fixed directions, cached: free friction alone lets a pile creep on, holding friction
// alone lets an edge stand), and contacts that leave an overlap of up to kRestSlopMm alone and
// push deeper overlap back through the velocity (split impulse's moves along a slanted contact
// slide resting parts a little every step, so a pile never comes to rest). Velocities at rest are
// small, so the pile is stepped at rest_time_step_s. A triangle-mesh tote holds throughout (a
// part sliding freely passes through its floor). docs/results.md, "Piles at rest" and "Single
// flat boxes", has the figures.
constexpr int kDropIterations = 20;
constexpr double kPileLandedMm = 1.0;
constexpr double kPileLandedDeg = 1.0;
constexpr double kPileLandedWindowS = 0.25;
constexpr double kRestSlopMm = 0.01;
// at rest, a part whose points all moved less than this since its contacts were searched keeps
// them against other such parts and the bin (StillContacts), mm: a fifth of the slop, a fiftieth
// of the settle rule's 0.1 mm; docs/results.md, "Speed", has what it saves and what more costs
constexpr double kStillMm = 0.002;
constexpr int kFreeFriction = SOLVER_USE_WARMSTARTING | SOLVER_SIMD;
constexpr int kHoldingFriction =
    SOLVER_USE_WARMSTARTING | SOLVER_SIMD | SOLVER_USE_2_FRICTION_DIRECTIONS |
    SOLVER_ENABLE_FRICTION_DIRECTION_CACHING | SOLVER_DISABLE_VELOCITY_DEPENDENT_FRICTION_DIRECTION;

// angular damping, fraction of angular velocity lost per second: kills the slow rocking that
// Bullet's contact solver otherwise sustains for an L resting on an edge (hardly slows a tumble)
constexpr double kAngularDamping = 0.3;

// the floor's collision box reaches at least this far down (nothing tunnels through it), mm
constexpr double kMinFloorThicknessMm = 20;

// a released part rests in the pile once it moved less than 10 mm over 0.1 s (slower than
// 100 mm/s; turning not counted)
constexpr RestRule kInPileRule{10, 180, 0.1, 0};

// sequential drops: a part has landed once it moved less than 1 mm and 2 degrees over 0.1 s,
// or 2 s after its release
constexpr RestRule kPartLandedRule{1, 2, 0.1, 2};

// a part reaching further than this beyond the inner walls' planes is outside the bin (below the
// rim) or leans over the rim (above it), mm
constexpr double kOverhangToleranceMm = 1;

// releases and rest rules are checked this often, s of simulated time
constexpr double kCheckIntervalS = 0.01;

// PickOrder: spacing of the vertical rays over the bin opening, mm, and the fraction of a part's
// rays that may meet another part first with the part still counting as on top (grazing edges)
constexpr double kPickRayPitchMm = 2;
constexpr double kPickCoveredFraction = 0.02;

btScalar ToSim(double mm) { return static_cast<btScalar>(mm * kSimPerMm); }

btVector3 ToSim(const Eigen::Vector3d& mm) {
  return btVector3(ToSim(mm.x()), ToSim(mm.y()), ToSim(mm.z()));
}

btTransform ToSim(const Eigen::Isometry3d& pose_mm) {
  const Eigen::Quaterniond q(pose_mm.linear());
  return btTransform(btQuaternion(static_cast<btScalar>(q.x()), static_cast<btScalar>(q.y()),
                                  static_cast<btScalar>(q.z()), static_cast<btScalar>(q.w())),
                     ToSim(pose_mm.translation()));
}

Eigen::Isometry3d FromSim(const btTransform& pose) {
  const btQuaternion q = pose.getRotation();
  Eigen::Isometry3d result = Eigen::Isometry3d::Identity();
  result.linear() = Eigen::Quaterniond(q.w(), q.x(), q.y(), q.z()).normalized().toRotationMatrix();
  const btVector3& t = pose.getOrigin();
  result.translation() = Eigen::Vector3d(t.x(), t.y(), t.z()) / kSimPerMm;
  return result;
}

// Everything one Simulate() call owns. Members are destroyed in reverse order: the world first,
// then the bodies and shapes it referred to.
struct World {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  // the same contact points with fewer queries: hull pieces found apart from another piece are
  // not searched against it again until they may have moved half of kConvexLookAheadMm
  ConvexPairs convex_pairs{&dispatcher, ToSim(kConvexLookAheadMm)};

  // convex pairs get a whole contact manifold in one step (Bullet's perturbation of the first
  // contact, 3 times), not one point per step: a part lying on a face is held at its corners at
  // once instead of rocking on one point while the manifold fills
  World()
      : world(std::make_unique<btDiscreteDynamicsWorld>(&dispatcher, &broadphase, &solver,
                                                        &configuration)) {
    configuration.setConvexConvexMultipointIterations();
    configuration.setPlaneConvexMultipointIterations();
  }
  ~World() {
    for (auto& body : bodies) world->removeRigidBody(body.get());
    world.reset();
  }

  template <typename Shape, typename... Args>
  Shape* AddShape(Args&&... args) {
    auto shape = std::make_unique<Shape>(std::forward<Args>(args)...);
    Shape* raw = shape.get();
    shapes.push_back(std::move(shape));
    return raw;
  }

  btRigidBody* AddBody(const btRigidBody::btRigidBodyConstructionInfo& info) {
    bodies.push_back(std::make_unique<btRigidBody>(info));
    world->addRigidBody(bodies.back().get());
    return bodies.back().get();
  }
};

}  // namespace

struct PileSimulator::Model {
  BinSpec bin;
  SimulationParams params;
  std::vector<TypeModel> types;
  // a tote mesh's collision shape, built once: static and only read while simulating, so every
  // world shares it (the triangles must outlive the shape)
  std::unique_ptr<btTriangleMesh> tote_triangles;
  std::unique_ptr<btBvhTriangleMeshShape> tote_shape;
  double table_z_mm = 0;  // the table under a tote mesh: its lowest point

  // free friction until the parts have landed, then the holding friction (a tote mesh holds
  // throughout: a part sliding with free friction passed its thin floor)
  bool FreeWhileFalling() const { return params.free_friction_while_falling && !tote_shape; }
};

PileSimulator::PileSimulator(const TriangleMesh& part,
                             const std::vector<TriangleMesh>& collision_pieces,
                             const PartPhysics& physics, const BinSpec& bin,
                             const SimulationParams& params, const std::string& cache_dir)
    : PileSimulator(std::vector<PartType>{PartType{part, collision_pieces, physics, ""}}, bin,
                    params, cache_dir) {}

PileSimulator::PileSimulator(const std::vector<PartType>& types, const BinSpec& bin,
                             const SimulationParams& params, const std::string& cache_dir) {
  CheckInputs(bin, params);
  if (types.empty()) throw std::runtime_error("PileSimulator: no part types");

  auto model = std::make_unique<Model>();
  model->bin = bin;
  model->params = params;
  for (size_t t = 0; t < types.size(); ++t) {
    const std::string what =
        !types[t].name.empty() ? types[t].name + ": "
                               : (types.size() > 1 ? "part type " + std::to_string(t) + ": " : "");
    model->types.push_back(MakeTypeModel(types[t], what, cache_dir));
  }

  // a tote mesh collides as a static triangle mesh (BVH), built here once
  if (!bin.mesh.triangles.empty()) {
    model->tote_triangles = std::make_unique<btTriangleMesh>();
    for (const auto& t : bin.mesh.triangles) {
      const auto corner = [&](int k) {
        return ToSim(Eigen::Vector3d(bin.mesh.positions_mm[t[k]].cast<double>()));
      };
      model->tote_triangles->addTriangle(corner(0), corner(1), corner(2), false);
    }
    model->tote_shape = std::make_unique<btBvhTriangleMeshShape>(model->tote_triangles.get(), true);
    model->tote_shape->setMargin(ToSim(kMarginMm));
    model->table_z_mm = Bounds(bin.mesh).min().z();
  }
  model_ = std::move(model);
}

PileSimulator::~PileSimulator() = default;
PileSimulator::PileSimulator(PileSimulator&&) noexcept = default;
PileSimulator& PileSimulator::operator=(PileSimulator&&) noexcept = default;

namespace {

// the model of `type`, or an error naming it
template <typename Types>
const auto& TypeAt(const Types& types, int type) {
  if (type < 0 || type >= static_cast<int>(types.size())) {
    throw std::runtime_error("PileSimulator: no part type " + std::to_string(type) +
                             " (there are " + std::to_string(types.size()) + ")");
  }
  return types[type];
}

}  // namespace

std::string PileSimulator::CollisionDescription(int type) const {
  return TypeAt(model_->types, type).description;
}

double PileSimulator::mass_kg(int type) const { return TypeAt(model_->types, type).mass.mass_kg; }

const std::vector<HullFace>& PileSimulator::hull_faces(int type) const {
  return TypeAt(model_->types, type).hull_faces;
}

PileResult PileSimulator::Simulate(int count, uint64_t seed) const {
  if (count < 0) {
    throw std::runtime_error("PileSimulator::Simulate: count must be >= 0, got " +
                             std::to_string(count));
  }
  return Simulate(std::vector<int>(count, 0), seed);
}

namespace {

// Bullet multiplies the two bodies' coefficients: each gets the square root, so a contact
// gets the geometric mean of the two surfaces' values
btScalar Root(double value) { return static_cast<btScalar>(std::sqrt(value)); }

// A world with gravity, the solver and the bin set up, into which parts are put: what
// Simulate, Resettle and PickOrder share.
class PileWorld {
 public:
  // the bin: a tote mesh (tote_shape, its lowest point at bottom_z_mm), or floor and four walls
  // as a static compound of boxes. Nothing is under it: a part that falls past the bin's bottom
  // has left the bin, and the drop stops there (a table cost every part a collision test per
  // step and caught only parts that make the drop a redraw anyway)
  PileWorld(const BinSpec& bin, const std::vector<TypeModel>& types, btCollisionShape* tote_shape,
            double tote_bottom_z_mm, int solver_iterations)
      : types_(types), shape_of_type_(types.size(), nullptr), inertia_of_type_(types.size()) {
    // gravity and the contact solver, falling with holding friction (see Fall and Rest)
    w_.world->setGravity(btVector3(0, 0, ToSim(-kGravityMmS2)));
    btContactSolverInfo& solver = w_.world->getSolverInfo();
    solver.m_warmstartingFactor = static_cast<btScalar>(kWarmStartingFactor);
    solver.m_splitImpulsePenetrationThreshold = 0;
    solver.m_restitutionVelocityThreshold = ToSim(kRestitutionThresholdMmS);
    solver_iterations_ = solver_iterations;
    Fall(false);
    if (tote_shape != nullptr) {
      btRigidBody::btRigidBodyConstructionInfo info(0, nullptr, tote_shape);
      info.m_friction = Root(bin.friction);
      info.m_restitution = Root(bin.restitution);
      w_.AddBody(info);
      bottom_z_mm_ = tote_bottom_z_mm;
      return;
    }
    const double l = bin.inner_length_mm / 2;
    const double wd = bin.inner_width_mm / 2;
    const double h = bin.inner_height_mm;
    const double t = bin.wall_mm;
    auto* compound = w_.AddShape<btCompoundShape>(false, 5);
    auto add_box = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
      auto* box = w_.AddShape<btBoxShape>(ToSim(Eigen::Vector3d((hi - lo) / 2)));
      box->setMargin(ToSim(kMarginMm));
      compound->addChildShape(btTransform(btQuaternion::getIdentity(), ToSim((lo + hi) / 2)), box);
    };
    // the floor's box reaches down into the table, so nothing tunnels through a thin floor
    add_box({-l - t, -wd - t, -std::max(t, kMinFloorThicknessMm)}, {l + t, wd + t, 0});
    add_box({-l - t, -wd - t, 0}, {-l, wd + t, h});
    add_box({l, -wd - t, 0}, {l + t, wd + t, h});
    add_box({-l, -wd - t, 0}, {l, -wd, h});
    add_box({-l, wd, 0}, {l, wd + t, h});
    btRigidBody::btRigidBodyConstructionInfo info(0, nullptr, compound);
    info.m_friction = Root(bin.friction);
    info.m_restitution = Root(bin.restitution);
    w_.AddBody(info);
    bottom_z_mm_ = -std::max(t, kMinFloorThicknessMm);
  }

  // Builds the collision shape of each type in `types` not built yet: a compound of its pieces
  // around the centre of mass, principal axes.
  void AddShapes(const std::vector<int>& types) {
    for (int type : types) {
      if (shape_of_type_[type] != nullptr) continue;
      const TypeModel& tm = types_[type];
      auto* shape = w_.AddShape<btCompoundShape>(true, static_cast<int>(tm.pieces.size()));
      for (const Piece& piece : tm.pieces) {
        btCollisionShape* child = nullptr;
        if (piece.is_box) {
          child = w_.AddShape<btBoxShape>(ToSim(piece.half_extents_mm));
        } else {
          auto* hull = w_.AddShape<btConvexHullShape>();
          for (const auto& p : piece.points_mm) hull->addPoint(ToSim(p), false);
          hull->recalcLocalAabb();
          child = hull;
        }
        child->setMargin(ToSim(piece.margin_mm));
        shape->addChildShape(ToSim(piece.body_from_piece), child);
      }
      shape_of_type_[type] = shape;
      const Eigen::Vector3d& moments = tm.mass.principal_moments_kg_mm2;
      const double inertia_scale = kSimPerMm * kSimPerMm;
      inertia_of_type_[type] = btVector3(static_cast<btScalar>(moments.x() * inertia_scale),
                                         static_cast<btScalar>(moments.y() * inertia_scale),
                                         static_cast<btScalar>(moments.z() * inertia_scale));
    }
  }

  // Puts a part of `type` at rest with its mesh frame at `world_from_object`.
  btRigidBody* AddPart(int type, const Eigen::Isometry3d& world_from_object) {
    AddShapes({type});
    const TypeModel& tm = types_[type];
    btRigidBody::btRigidBodyConstructionInfo info(static_cast<btScalar>(tm.mass.mass_kg), nullptr,
                                                  shape_of_type_[type], inertia_of_type_[type]);
    info.m_startWorldTransform = ToSim(world_from_object * tm.object_from_body);
    info.m_friction = Root(tm.physics.friction);
    info.m_restitution = Root(tm.physics.restitution);
    info.m_rollingFriction = ToSim(tm.physics.rolling_friction_mm);
    info.m_spinningFriction = ToSim(tm.physics.rolling_friction_mm);
    btRigidBody* body = w_.AddBody(info);
    // the settle rule decides when to stop; sleeping bodies would freeze mid-motion
    body->setActivationState(DISABLE_DEACTIVATION);
    body->setDamping(0, static_cast<btScalar>(kAngularDamping));
    // friction anchors: a contact point is kept, not replaced, while its friction stays inside
    // the Coulomb cone, and the solver holds it where it is (static friction); without them a
    // pile creeps on for ever under velocity-only friction (in stackgen-rest-check the heaps
    // sank 6.7 mm in the 60 s after they were published)
    body->setCollisionFlags(body->getCollisionFlags() | btCollisionObject::CF_HAS_FRICTION_ANCHOR);
    parts_.push_back(body);
    part_types_.push_back(type);
    return body;
  }

  // whether a part's centre of mass fell a part size below the bin's bottom: outside for good
  bool FellOut() const {
    for (size_t b = 0; b < parts_.size(); ++b) {
      const double z_mm = parts_[b]->getCenterOfMassPosition().z() / kSimPerMm;
      if (z_mm < bottom_z_mm_ - types_[part_types_[b]].max_extent_mm) return true;
    }
    return false;
  }

  // the mesh frame of a part, mm
  Eigen::Isometry3d WorldFromObject(const btRigidBody* body, int type) const {
    return FromSim(body->getWorldTransform()) * types_[type].body_from_object;
  }

  // the deepest penetration over the current contacts, mm
  double MaxPenetrationMm() {
    double deepest = 0;
    for (int i = 0; i < w_.dispatcher.getNumManifolds(); ++i) {
      const btPersistentManifold* manifold = w_.dispatcher.getManifoldByIndexInternal(i);
      for (int c = 0; c < manifold->getNumContacts(); ++c) {
        const double distance_mm = manifold->getContactPoint(c).getDistance() / kSimPerMm;
        deepest = std::max(deepest, -distance_mm);
      }
    }
    return deepest;
  }

  btDiscreteDynamicsWorld& world() { return *w_.world; }

  // The two phases of a pile (see kRestSlopMm). Falling: split-impulse contacts, with free
  // friction or holding friction.
  void Fall(bool free_friction) {
    btContactSolverInfo& solver = w_.world->getSolverInfo();
    solver.m_splitImpulse = true;
    solver.m_linearSlop = 0;
    solver.m_solverMode = free_friction ? kFreeFriction : kHoldingFriction;
    solver.m_numIterations =
        free_friction ? std::min(kDropIterations, solver_iterations_) : solver_iterations_;
  }
  // Landed: holding friction and contacts at rest, stepped `step_ratio` times as long as while
  // falling (the last step's impulses, where each step starts, grow with it), the contacts of
  // parts that lie still kept (StillContacts, kStillMm). Once only.
  void Rest(double step_ratio) {
    if (resting_) return;
    resting_ = true;
    still_ =
        std::make_unique<StillContacts>(w_.world.get(), &w_.dispatcher, parts_, ToSim(kStillMm));
    btContactSolverInfo& solver = w_.world->getSolverInfo();
    solver.m_splitImpulse = false;
    solver.m_linearSlop = ToSim(kRestSlopMm);
    solver.m_solverMode = kHoldingFriction;
    solver.m_numIterations = solver_iterations_;
    const auto scale = static_cast<btScalar>(step_ratio);
    for (int i = 0; i < w_.dispatcher.getNumManifolds(); ++i) {
      btPersistentManifold* manifold = w_.dispatcher.getManifoldByIndexInternal(i);
      for (int c = 0; c < manifold->getNumContacts(); ++c) {
        btManifoldPoint& point = manifold->getContactPoint(c);
        point.m_appliedImpulse *= scale;
        point.m_appliedImpulseLateral1 *= scale;
        point.m_appliedImpulseLateral2 *= scale;
      }
    }
  }

  // Every contact searched every step from now on, as Bullet does (a strict check's physics).
  void SearchEveryStep() { still_.reset(); }

  // the poses of `bodies` (their centres of mass), mm
  static std::vector<Eigen::Isometry3d> Poses(const std::vector<btRigidBody*>& bodies) {
    std::vector<Eigen::Isometry3d> poses;
    poses.reserve(bodies.size());
    for (const btRigidBody* body : bodies) poses.push_back(FromSim(body->getWorldTransform()));
    return poses;
  }

 private:
  const std::vector<TypeModel>& types_;
  World w_;
  double bottom_z_mm_ = 0;
  int solver_iterations_ = 0;  // with holding friction
  bool resting_ = false;
  std::vector<btCompoundShape*> shape_of_type_;
  std::vector<btVector3> inertia_of_type_;
  std::vector<btRigidBody*> parts_;  // in the order added
  std::vector<int> part_types_;
  std::unique_ptr<StillContacts> still_;  // at rest; before the world goes
};

// Adds the mesh frame of a part whose body (centre of mass) is at `world_from_body` to `result`
// and counts it if it is outside the bin (its centre of mass is not in the bin, up to one part
// size above the rim, for an overfull pile is still in the bin; or it hangs beyond a wall's
// plane below the rim) or leans over the rim.
void AddPlacement(const BinSpec& bin, const TypeModel& tm, const Eigen::Isometry3d& world_from_body,
                  PileResult* result) {
  const Eigen::Isometry3d world_from_object = world_from_body * tm.body_from_object;
  result->world_from_object.push_back(world_from_object);
  const Eigen::Vector3d com = world_from_body.translation();
  const bool inside = std::abs(com.x()) <= bin.inner_length_mm / 2 &&
                      std::abs(com.y()) <= bin.inner_width_mm / 2 && com.z() >= 0 &&
                      com.z() <= bin.inner_height_mm + tm.max_extent_mm;
  // parts reaching beyond the walls' planes: hanging outside below the rim, leaning over it
  // above
  bool hooked = false, leaning = false;
  for (const auto& v : tm.hull_vertices_mm) {
    const Eigen::Vector3d p = world_from_object * v;
    const bool beyond = std::abs(p.x()) > bin.inner_length_mm / 2 + kOverhangToleranceMm ||
                        std::abs(p.y()) > bin.inner_width_mm / 2 + kOverhangToleranceMm;
    if (beyond && p.z() < bin.inner_height_mm - kOverhangToleranceMm) hooked = true;
    if (beyond) leaning = true;
  }
  if (!inside || hooked) {
    ++result->num_outside;
  } else if (leaning) {
    ++result->num_overhanging;
  }
}

// Throws std::invalid_argument unless the rule's thresholds, window and cap are positive.
void CheckRule(const RestRule& rule) {
  if (!(rule.translation_mm > 0 && rule.rotation_deg > 0 && rule.window_s > 0 &&
        rule.max_time_s > 0 && rule.window_s <= rule.max_time_s)) {
    throw std::invalid_argument(
        "PileSimulator: a rest rule's thresholds, window and cap must be positive, the window "
        "no longer than the cap");
  }
}

// The settle rule of `params` (capped at max_sim_time_s), and the rule that a pile has landed,
// which ends the falling phase (kPileLanded*, or the settle rule where it is looser).
RestRule SettleRule(const SimulationParams& params) {
  return {params.settle_translation_mm, params.settle_rotation_deg, params.settle_window_s,
          params.max_sim_time_s};
}
RestRule LandingRule(const SimulationParams& params) {
  return {std::max(params.settle_translation_mm, kPileLandedMm),
          std::max(params.settle_rotation_deg, kPileLandedDeg),
          std::min(params.settle_window_s, kPileLandedWindowS), params.max_sim_time_s};
}

// What a check asks of the stepping loop, and how a phase ended.
enum class Verdict { kGoOn, kAtRest, kTimeUp };
enum class Ended { kAtRest, kTimeUp, kFellOut };

// The one stepping loop of the simulator: steps `w` by `dt` and every kCheckIntervalS of
// simulated time asks `check(time_s)` whether to go on; ends when it says at rest or time up,
// when a part fell out of the bin, or after `max_s`. *time_s runs on from its value.
template <typename Check>
Ended Step(PileWorld* w, double dt, double max_s, double* time_s, Check check) {
  const int check_every = std::max(1, static_cast<int>(std::lround(kCheckIntervalS / dt)));
  const int max_steps = static_cast<int>(std::ceil(max_s / dt - 1e-9));
  const double start_s = *time_s;
  for (int step = 1; step <= max_steps; ++step) {
    w->world().stepSimulation(static_cast<btScalar>(dt), 0, static_cast<btScalar>(dt));
    *time_s = start_s + step * dt;
    if (step % check_every != 0) continue;
    if (w->FellOut()) return Ended::kFellOut;
    switch (check(*time_s)) {
      case Verdict::kGoOn:
        break;
      case Verdict::kAtRest:
        return Ended::kAtRest;
      case Verdict::kTimeUp:
        return Ended::kTimeUp;
    }
  }
  return Ended::kTimeUp;
}

// Steps `bodies` until `rule` holds, within `max_s`; its window starts at the first check, or
// with `from_now` at the poses now. No bodies are at rest at once.
Ended StepUntilRest(PileWorld* w, double dt, const RestRule& rule,
                    const std::vector<btRigidBody*>& bodies, double max_s, double* time_s,
                    bool from_now = false) {
  if (bodies.empty()) return Ended::kAtRest;
  SettleDetector detector(rule);
  if (from_now && detector.AddSample(*time_s, PileWorld::Poses(bodies))) return Ended::kAtRest;
  return Step(w, dt, max_s, time_s, [&](double now) {
    return detector.AddSample(now, PileWorld::Poses(bodies)) ? Verdict::kAtRest : Verdict::kGoOn;
  });
}

// The rest phase of a landed pile: at rest by the settle rule within `max_s`. Whether it is.
bool RestPhase(const SimulationParams& params, const std::vector<btRigidBody*>& bodies,
               double max_s, PileWorld* w, double* time_s) {
  w->Rest(params.rest_time_step_s / params.time_step_s);
  return StepUntilRest(w, params.rest_time_step_s, SettleRule(params), bodies, max_s, time_s) ==
         Ended::kAtRest;
}

// Puts the parts a ReleaseQueue lets go into the world, at rest, and keeps what the queue asks
// about the bodies already in: their boxes, which rest in the pile, whether the last one landed.
class Dropper {
 public:
  Dropper(const std::vector<TypeModel>& type_models, ReleaseQueue* queue, PileWorld* w, int count)
      : type_models_(type_models), queue_(*queue), w_(*w), body_of_part_(count, nullptr) {}

  // Releases what the queue lets go at `time_s`; returns whether any part was released.
  bool ReleaseDue(double time_s) {
    // the released bodies' boxes, which of them rest in the pile, whether the last one landed
    const std::vector<Eigen::Isometry3d> poses = PileWorld::Poses(bodies_);
    in_pile_.AddSample(time_s, poses);
    landed_.AddSample(time_s, poses);
    std::vector<Box> boxes;
    std::vector<bool> in_pile;
    for (size_t b = 0; b < bodies_.size(); ++b) {
      const TypeModel& tm = type_models_[types_[b]];
      const Eigen::Isometry3d world_from_object = w_.WorldFromObject(bodies_[b], types_[b]);
      Box box;
      for (const auto& v : tm.hull_vertices_mm) box.Add(world_from_object * v);
      boxes.push_back(box);
      in_pile.push_back(in_pile_.AtRest(b));
    }
    const bool landed = bodies_.empty() || landed_.AtRest(bodies_.size() - 1) ||
                        time_s - released_at_s_.back() >= kPartLandedRule.max_time_s;
    // the new bodies, at rest
    const auto parts = queue_.Next(time_s, std::move(boxes), in_pile, landed);
    for (const auto& [part, z] : parts) {
      const int type = queue_.release(part).type;
      btRigidBody* body = w_.AddPart(type, queue_.release(part).WorldFromObjectAt(z));
      body_of_part_[part] = body;
      bodies_.push_back(body);
      types_.push_back(type);
      released_at_s_.push_back(time_s);
    }
    return !parts.empty();
  }

  // each part's body; null while it waits
  const std::vector<btRigidBody*>& body_of_part() const { return body_of_part_; }

 private:
  const std::vector<TypeModel>& type_models_;
  ReleaseQueue& queue_;
  PileWorld& w_;
  std::vector<btRigidBody*> body_of_part_;
  // the released bodies in order of release, their types and release times
  std::vector<btRigidBody*> bodies_;
  std::vector<int> types_;
  std::vector<double> released_at_s_;
  SettleDetector in_pile_{kInPileRule};
  SettleDetector landed_{kPartLandedRule};
};

// Places the parts of `types` (bodies) in `result`, and the deepest penetration now.
void Place(const BinSpec& bin, const std::vector<TypeModel>& type_models,
           const std::vector<int>& types, const std::vector<btRigidBody*>& bodies, PileWorld* w,
           PileResult* result) {
  for (size_t i = 0; i < types.size(); ++i) {
    AddPlacement(bin, type_models[types[i]], FromSim(bodies[i]->getWorldTransform()), result);
  }
  result->max_penetration_mm = w->MaxPenetrationMm();
}

// Goes on stepping the pile of `bodies` (of `types`) at rest, every contact searched every step,
// until it is at rest by `rule` (its window reaching back to the poses now) or rule.max_time_s
// more passed; `after` gets the poses and checks then, settled (at rest by the rule) and the time
// it went on.
void GoOnToRest(const BinSpec& bin, const SimulationParams& params,
                const std::vector<TypeModel>& type_models, const RestRule& rule,
                const std::vector<int>& types, const std::vector<btRigidBody*>& bodies,
                PileWorld* w, PileResult* after) {
  *after = PileResult{};
  w->Rest(params.rest_time_step_s / params.time_step_s);
  w->SearchEveryStep();
  double time_s = 0;
  after->settled = StepUntilRest(w, params.rest_time_step_s, rule, bodies, rule.max_time_s,
                                 &time_s, true) == Ended::kAtRest;
  after->simulated_s = time_s;
  Place(bin, type_models, types, bodies, w, after);
}

}  // namespace

PileResult PileSimulator::Simulate(const std::vector<int>& types, uint64_t seed) const {
  return Simulate(types, seed, kStrictRestRule, nullptr);
}

PileResult PileSimulator::Simulate(const std::vector<int>& types, uint64_t seed,
                                   const RestRule& rule, PileResult* after) const {
  if (after != nullptr) CheckRule(rule);
  const Model& m = *model_;
  for (int type : types) TypeAt(m.types, type);
  const int count = static_cast<int>(types.size());
  const BinSpec& bin = m.bin;
  const SimulationParams& params = m.params;
  PileWorld w(bin, m.types, m.tote_shape.get(), m.table_z_mm, params.solver_iterations);
  if (count == 0) {
    PileResult empty;
    empty.settled = true;
    if (after != nullptr) *after = empty;
    return empty;
  }
  w.AddShapes(types);
  w.Fall(m.FreeWhileFalling());

  std::mt19937_64 engine(seed);
  ReleaseQueue queue(DrawReleases(m.types, types, bin, params, engine),
                     bin.inner_height_mm + params.drop_height_mm,
                     params.drop_mode == DropMode::kSequential);
  Dropper dropper(m.types, &queue, &w, count);
  dropper.ReleaseDue(0);
  const std::vector<btRigidBody*>& body_of_part = dropper.body_of_part();

  // falling: every part released (at most kPartLandedRule.max_time_s per part, waves kStallS),
  // then landed (the window starts after the last release); then at rest by the settle rule;
  // both within max_sim_time_s after the last release
  double time_s = 0;
  double last_release_s = 0;
  SettleDetector landing(LandingRule(params));
  const double release_cap_s = count * std::max(kPartLandedRule.max_time_s, kStallS);
  PileResult result;
  const Ended landed =
      Step(&w, params.time_step_s, release_cap_s + params.max_sim_time_s, &time_s, [&](double now) {
        if (!queue.empty()) {
          if (dropper.ReleaseDue(now)) last_release_s = now;
          return Verdict::kGoOn;
        }
        if (now - last_release_s >= params.max_sim_time_s - 1e-9) return Verdict::kTimeUp;
        return landing.AddSample(now, PileWorld::Poses(body_of_part)) ? Verdict::kAtRest
                                                                      : Verdict::kGoOn;
      });
  if (landed == Ended::kAtRest) {
    result.settled = RestPhase(params, body_of_part,
                               last_release_s + params.max_sim_time_s - time_s, &w, &time_s);
  }
  result.simulated_s = time_s;

  // the mesh frame of each part, and whether it is in the bin
  for (int i = 0; i < count; ++i) {
    if (body_of_part[i] == nullptr) {
      // still waiting when time ran out: it never entered the bin
      result.world_from_object.push_back(queue.release(i).WorldFromObjectAt(queue.release_z_mm()));
      ++result.num_outside;
      continue;
    }
    AddPlacement(bin, m.types[types[i]], FromSim(body_of_part[i]->getWorldTransform()), &result);
  }
  result.max_penetration_mm = w.MaxPenetrationMm();
  if (after != nullptr) {
    if (std::find(body_of_part.begin(), body_of_part.end(), nullptr) != body_of_part.end()) {
      *after = result;  // a part never entered the bin: nothing to go on with
      after->settled = false;
      after->simulated_s = 0;
    } else {
      GoOnToRest(bin, params, m.types, rule, types, body_of_part, &w, after);
    }
  }
  return result;
}

PileResult PileSimulator::Resettle(const std::vector<int>& types,
                                   const std::vector<Eigen::Isometry3d>& world_from_object) const {
  return Resettle(types, world_from_object, kStrictRestRule, nullptr);
}

PileResult PileSimulator::Resettle(const std::vector<int>& types,
                                   const std::vector<Eigen::Isometry3d>& world_from_object,
                                   const RestRule& rule, PileResult* after) const {
  const Model& m = *model_;
  for (int type : types) TypeAt(m.types, type);
  if (types.size() != world_from_object.size()) {
    throw std::invalid_argument("PileSimulator::Resettle: " + std::to_string(types.size()) +
                                " types but " + std::to_string(world_from_object.size()) +
                                " poses");
  }
  if (after != nullptr) CheckRule(rule);
  const SimulationParams& params = m.params;
  PileWorld w(m.bin, m.types, m.tote_shape.get(), m.table_z_mm, params.solver_iterations);
  w.AddShapes(types);
  std::vector<btRigidBody*> bodies;
  for (size_t i = 0; i < types.size(); ++i)
    bodies.push_back(w.AddPart(types[i], world_from_object[i]));

  // as in Simulate, the window of the landing rule starting at once: landed, then at rest by the
  // settle rule, within max_sim_time_s
  w.Fall(m.FreeWhileFalling());
  double time_s = 0;
  PileResult result;
  if (StepUntilRest(&w, params.time_step_s, LandingRule(params), bodies, params.max_sim_time_s,
                    &time_s) == Ended::kAtRest) {
    result.settled = RestPhase(params, bodies, params.max_sim_time_s - time_s, &w, &time_s);
  }
  result.simulated_s = time_s;
  Place(m.bin, m.types, types, bodies, &w, &result);
  if (after != nullptr) GoOnToRest(m.bin, params, m.types, rule, types, bodies, &w, after);
  return result;
}

LiftResult PileSimulator::Lift(const std::vector<int>& types,
                               const std::vector<Eigen::Isometry3d>& world_from_object, int part,
                               const Eigen::Vector3d& point_mm, const Eigen::Vector3d& normal,
                               const LiftParams& lift) const {
  const Model& m = *model_;
  for (int type : types) TypeAt(m.types, type);
  if (types.size() != world_from_object.size() || part < 0 ||
      part >= static_cast<int>(types.size())) {
    throw std::invalid_argument("PileSimulator::Lift: part " + std::to_string(part) + " of " +
                                std::to_string(types.size()) + " types and " +
                                std::to_string(world_from_object.size()) + " poses");
  }
  const bool jaws = lift.hold == LiftParams::Hold::kJaws;
  if (!point_mm.allFinite() || !(std::abs(normal.norm() - 1) < 1e-6) ||
      !(lift.cup_diameter_mm > 0) || !(lift.vacuum_kpa >= 0) || !(lift.lift_mm > 0) ||
      !(lift.lift_speed_mm_s > 0) ||
      (jaws && (!(std::abs(lift.jaw_axis.norm() - 1) < 1e-6) || !(lift.jaw_grip_force_n > 0) ||
                !(lift.jaw_friction > 0)))) {
    throw std::invalid_argument(
        "PileSimulator::Lift: the point must be finite, the normal (and the jaws' axis) of unit "
        "length, the cup's diameter, the grip, friction, lift and speed positive and the vacuum "
        "not negative");
  }
  const SimulationParams& params = m.params;
  const double dt = params.rest_time_step_s;
  PileWorld w(m.bin, m.types, m.tote_shape.get(), m.table_z_mm, params.solver_iterations);
  w.AddShapes(types);
  std::vector<btRigidBody*> bodies;
  for (size_t i = 0; i < types.size(); ++i) {
    bodies.push_back(w.AddPart(types[i], world_from_object[i]));
  }
  w.Rest(params.rest_time_step_s / params.time_step_s);
  const auto step = [&](double seconds, const std::function<void(double)>& each) {
    const int steps = static_cast<int>(std::lround(seconds / dt));
    for (int k = 1; k <= steps; ++k) {
      w.world().stepSimulation(static_cast<btScalar>(dt), 0, static_cast<btScalar>(dt));
      each(k * dt);
    }
  };

  // the contacts take up the load; the poses then are where the lift starts
  step(kLiftSettleS, [](double) {});
  const std::vector<Eigen::Isometry3d> start = PileWorld::Poses(bodies);

  // the hold: a cup's ball joint at the contact, or the jaws' hinge about the closing line
  // through the point, its world end rising along the pull; it lets go when an impulse above
  // its force x dt is needed (kg cm / s: N s x 100)
  btRigidBody* held = bodies[static_cast<size_t>(part)];
  const Eigen::Isometry3d body_from_world = FromSim(held->getCenterOfMassTransform()).inverse();
  const Eigen::Vector3d pivot_in_body = body_from_world * point_mm;
  std::unique_ptr<btTypedConstraint> hold;
  double force_n = 0;
  if (jaws) {
    const Eigen::Vector3d axis_in_body = body_from_world.linear() * lift.jaw_axis;
    hold = std::make_unique<btHingeConstraint>(*held, ToSim(pivot_in_body),
                                              btVector3(static_cast<btScalar>(axis_in_body.x()),
                                                        static_cast<btScalar>(axis_in_body.y()),
                                                        static_cast<btScalar>(axis_in_body.z())));
    force_n = 2 * lift.jaw_friction * lift.jaw_grip_force_n;
  } else {
    hold = std::make_unique<btPoint2PointConstraint>(*held, ToSim(pivot_in_body));
    const double area_m2 = M_PI * std::pow(lift.cup_diameter_mm / 2000, 2);
    force_n = lift.vacuum_kpa * 1000 * area_m2;
  }
  const auto move_to = [&](const Eigen::Vector3d& world_mm) {
    if (jaws) {
      static_cast<btHingeConstraint*>(hold.get())->getBFrame().setOrigin(ToSim(world_mm));
    } else {
      static_cast<btPoint2PointConstraint*>(hold.get())->setPivotB(ToSim(world_mm));
    }
  };
  hold->setBreakingImpulseThreshold(static_cast<btScalar>(force_n * dt * 100));
  move_to(point_mm);
  w.world().addConstraint(hold.get(), true);

  // the hold's rise: smooth (3 x^2 - 2 x^3), its top speed lift_speed_mm_s, so the part is not
  // jerked off the hold at the start
  LiftResult result;
  const double lift_s = 1.5 * lift.lift_mm / lift.lift_speed_mm_s;
  bool let_go = false;
  const Eigen::Isometry3d held_start = start[static_cast<size_t>(part)];
  step(lift_s + kLiftHoldS, [&](double t) {
    if (let_go) return;
    if (!hold->isEnabled()) {
      let_go = true;
      return;
    }
    const Eigen::Isometry3d now = FromSim(held->getWorldTransform());
    result.rise_mm = std::max(result.rise_mm, (now.translation() - held_start.translation()).z());
    const Eigen::AngleAxisd turn(held_start.linear().transpose() * now.linear());
    result.swing_deg = std::max(result.swing_deg, std::abs(turn.angle()) * 180 / M_PI);
    const double x = std::min(t / lift_s, 1.0);
    move_to(point_mm + x * x * (3 - 2 * x) * lift.lift_mm * normal);
  });
  w.world().removeConstraint(hold.get());
  result.outcome = !let_go                              ? LiftResult::Outcome::kLifted
                   : result.rise_mm >= lift.lift_mm / 5 ? LiftResult::Outcome::kDropped
                                                        : LiftResult::Outcome::kStuck;
  const std::vector<Eigen::Isometry3d> end = PileWorld::Poses(bodies);
  for (size_t i = 0; i < bodies.size(); ++i) {
    result.moved_mm.push_back(static_cast<int>(i) == part
                                  ? 0.0
                                  : (end[i].translation() - start[i].translation()).norm());
  }
  return result;
}

std::vector<int> PileSimulator::PickOrder(
    const std::vector<int>& types, const std::vector<Eigen::Isometry3d>& world_from_object) const {
  const Model& m = *model_;
  for (int type : types) TypeAt(m.types, type);
  if (types.size() != world_from_object.size()) {
    throw std::invalid_argument("PileSimulator::PickOrder: " + std::to_string(types.size()) +
                                " types but " + std::to_string(world_from_object.size()) +
                                " poses");
  }
  PileWorld w(m.bin, m.types, m.tote_shape.get(), m.table_z_mm, m.params.solver_iterations);
  double top_mm = m.bin.inner_height_mm;
  for (size_t i = 0; i < types.size(); ++i) {
    // a ray's hit tells the part by its index (the bin keeps Bullet's -1)
    w.AddPart(types[i], world_from_object[i])->setUserIndex(static_cast<int>(i));
    top_mm =
        std::max(top_mm, world_from_object[i].translation().z() + m.types[types[i]].max_extent_mm);
  }

  // vertical rays on a grid over the opening: each counts for the part it meets first, and as
  // covering every other part it passes through. A compound part reports a hit for each of its
  // pieces on the ray: each part counts once, at its nearest hit, so a part's own lower pieces
  // never cover it
  std::vector<int> seen(types.size(), 0), covered(types.size(), 0);
  const int nx = std::max(1, static_cast<int>(std::floor(m.bin.inner_length_mm / kPickRayPitchMm)));
  const int ny = std::max(1, static_cast<int>(std::floor(m.bin.inner_width_mm / kPickRayPitchMm)));
  for (int ix = 0; ix < nx; ++ix) {
    for (int iy = 0; iy < ny; ++iy) {
      const double x = -m.bin.inner_length_mm / 2 + (ix + 0.5) * m.bin.inner_length_mm / nx;
      const double y = -m.bin.inner_width_mm / 2 + (iy + 0.5) * m.bin.inner_width_mm / ny;
      const btVector3 from = ToSim(Eigen::Vector3d(x, y, top_mm + 10));
      const btVector3 to = ToSim(Eigen::Vector3d(x, y, -1));
      btCollisionWorld::AllHitsRayResultCallback callback(from, to);
      w.world().rayTest(from, to, callback);
      // the parts along the ray, nearest first (the bin's floor ends it)
      std::vector<std::pair<btScalar, int>> along;
      for (int h = 0; h < callback.m_collisionObjects.size(); ++h) {
        along.emplace_back(callback.m_hitFractions[h],
                           callback.m_collisionObjects[h]->getUserIndex());
      }
      std::sort(along.begin(), along.end());
      std::vector<int> met;
      for (size_t h = 0; h < along.size() && along[h].second >= 0; ++h) {
        const int part = along[h].second;
        if (std::find(met.begin(), met.end(), part) != met.end()) continue;
        ++(met.empty() ? seen : covered)[part];
        met.push_back(part);
      }
    }
  }

  // parts on top (another part covers less than kPickCoveredFraction of the area seen of them)
  // first, most area seen from above first; then the higher centre of mass; then the lower index
  const auto on_top = [&](int i) {
    return covered[i] <= kPickCoveredFraction * (seen[i] + covered[i]);
  };
  std::vector<int> order(types.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  const auto com_z = [&](int i) {
    return (world_from_object[i] * m.types[types[i]].object_from_body).translation().z();
  };
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    if (on_top(a) != on_top(b)) return on_top(a);
    if (seen[a] != seen[b]) return seen[a] > seen[b];
    return com_z(a) > com_z(b);
  });
  return order;
}

}  // namespace stackgen
