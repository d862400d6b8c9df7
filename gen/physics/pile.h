#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "gen/mesh/mesh.h"
#include "gen/physics/hull_faces.h"
#include "gen/physics/settle_detector.h"
#include "stackgen_config.pb.h"

namespace stackgen {

// The structs below mirror parts of the config (types/stackgen_config.proto: BinConfig,
// PartConfig, PhysicsConfig) for the simulator, which tests also use on their own: their
// defaults are the schema's (its default instances), and PileSimulator checks their values
// against the schema's ranges, so each is stated once, there.

/// The bin, millimetres: an open box on z = 0 whose inner floor is centred at the origin, z up.
/// The inner floor is the plane z = 0 (the floor slab fills z in [-wall_mm, 0]) and the rim is at
/// z = inner_height_mm, as in MakeOpenBinMesh. Nothing is under the bin: a part whose centre
/// of mass falls one part size below the bin's bottom (z = -max(wall_mm, 20)) has left it, and
/// the drop stops there. With a `mesh` (a real tote, same frame), that mesh is the bin's
/// collision shape instead of the box (a static triangle mesh), its lowest point is the bottom,
/// and the inner sizes still say where parts are released and what counts as inside.
struct BinSpec {
  double inner_length_mm;  // along x
  double inner_width_mm;   // along y
  double inner_height_mm;  // inner floor to rim, along z
  double wall_mm;          // thickness of the floor and the walls (wall_thickness_mm)
  // Coulomb coefficient of the bin's surfaces, and its restitution
  double friction = config::BinConfig::default_instance().friction();
  double restitution = config::BinConfig::default_instance().restitution();
  TriangleMesh mesh;  // optional tote mesh, world frame, mm; empty = the box above
};

/// Material of a part type. A contact gets the geometric mean of the two surfaces' friction and
/// of their restitution.
struct PartPhysics {
  double density_kg_m3 = config::PartConfig::default_instance().density_kg_m3();
  double friction = config::PartConfig::default_instance().friction();  // Coulomb coefficient
  double restitution = config::PartConfig::default_instance().restitution();
  // lever arm resisting rolling and spinning, mm
  double rolling_friction_mm = config::PartConfig::default_instance().rolling_friction_mm();
};

/// One part type: its mesh (mm, closed, outward-wound), optional convex collision pieces (mm,
/// same frame; empty = decomposition or hull, see PileSimulator) and material.
struct PartType {
  TriangleMesh mesh;
  std::vector<TriangleMesh> collision_pieces;
  PartPhysics physics;
  /// What errors call it (e.g. its mesh file); empty: "part type N" when there are several.
  std::string name;
};

/// How parts are released into the bin.
enum class DropMode {
  /// random orientation and x, y over the opening; released in waves as space frees up
  kRandomVolume,
  /// the paper's: one by one from a fixed point, each once the previous one has landed
  kSequential,
};

/// How a pile is simulated and when it counts as settled. A pile goes through two phases: it
/// falls (parts released, time_step_s, split-impulse contacts, friction as below) until it has
/// landed (every part moved less than 1 mm and 1 degree over 0.25 s, or the settle rule where it
/// is looser), then it rests (holding friction, rest_time_step_s, contacts that push apart only
/// past a 0.01 mm overlap) until it is at rest by the settle rule, which publishes it.
struct SimulationParams {
  static const config::PhysicsConfig& Defaults() {
    return config::PhysicsConfig::default_instance();
  }
  double time_step_s = Defaults().time_step_s();  // fixed physics step while falling, s
  // fixed physics step once landed, s, at least time_step_s
  double rest_time_step_s = Defaults().rest_time_step_s();
  double max_sim_time_s = Defaults().max_sim_time_s();  // simulated-time cap after the last release
  // at rest when every body's centre of mass moved less than settle_translation_mm and turned
  // less than settle_rotation_deg over the last settle_window_s seconds (a sliding window)
  double settle_translation_mm = Defaults().settle_translation_mm();
  double settle_rotation_deg = Defaults().settle_rotation_deg();
  double settle_window_s = Defaults().settle_window_s();
  // gap between the rim and the lowest released part, mm
  double drop_height_mm = Defaults().drop_height_mm();
  DropMode drop_mode = DropMode::kRandomVolume;  // (the schema's RANDOM_VOLUME)
  // kSequential: x, y of the release, mm, inside the bin's opening
  Eigen::Vector2d drop_point_mm =
      Eigen::Vector2d(Defaults().drop_point_x_mm(), Defaults().drop_point_y_mm());
  int solver_iterations = Defaults().solver_iterations();  // contact solver, per step
  // velocity-aligned friction until landed
  bool free_friction_while_falling = Defaults().free_friction_while_falling();
};

/// A settled (or capped) pile.
struct PileResult {
  // mm, the MESH frame of each part (not its centre of mass)
  std::vector<Eigen::Isometry3d> world_from_object;
  // at rest by the settle rule: every body moved < settle_translation_mm and turned
  // < settle_rotation_deg over the last settle_window_s
  bool settled = false;
  // parts outside the bin: the centre of mass is not inside the bin's inner box (x,y within
  // inner size, z between the floor and the rim + one part size: an overfull pile still counts as
  // inside), or the part reaches more than 1 mm beyond an inner wall's plane below the rim (hooked
  // over the wall, hanging outside)
  int num_outside = 0;
  // parts inside by the rule above that reach more than 1 mm beyond an inner wall's plane above
  // the rim: leaning over the rim, as parts in a full real bin do
  int num_overhanging = 0;
  // simulated time until settled or the cap
  double simulated_s = 0;
  // deepest contact penetration at the end (part-part and part-bin)
  double max_penetration_mm = 0;
};

/// A suction cup or parallel jaws lifting one part of a pile (PileSimulator::Lift).
struct LiftParams {
  /// How the part is held: a suction cup (a ball joint at the point, so the part swings under
  /// it, holding vacuum_kpa x its area) or parallel jaws (a hinge about jaw_axis through the
  /// point, the midpoint of the two contacts, so the part turns between the fingers, holding
  /// 2 x jaw_friction x jaw_grip_force_n).
  enum class Hold { kCup, kJaws };
  Hold hold = Hold::kCup;
  double cup_diameter_mm = 15;   // the cup's lip diameter, > 0
  double vacuum_kpa = 60;        // the pressure difference it holds with, >= 0
  Eigen::Vector3d jaw_axis{1, 0, 0};  // kJaws: the closing line's direction, unit
  double jaw_grip_force_n = 40;       // kJaws: each finger's squeeze, > 0
  double jaw_friction = 0.5;          // kJaws: finger on part, > 0
  double lift_mm = 50;           // how far the hold rises along the pull direction, > 0
  double lift_speed_mm_s = 100;  // its top speed, > 0
};

/// What lifting a part did.
struct LiftResult {
  enum class Outcome {
    kLifted,   // lifted lift_mm and still held at the end
    kDropped,  // the cup let go after the part had risen a fifth of lift_mm
    kStuck,    // the cup let go before: the part is held in the pile
  };
  Outcome outcome = Outcome::kStuck;
  double swing_deg = 0;  // the part's largest turn from its pose at the start, while held
  double rise_mm = 0;    // how far its centre of mass rose, at most, while held
  /// For every part, how far its centre of mass moved from the start to the end (the lifted
  /// part: 0), mm.
  std::vector<double> moved_mm;
};

/// The strict check of a published pile (stackgen-rest-check's defaults): every part moved less
/// than 0.1 mm and 0.1 degree over 1 s, within 60 s.
inline constexpr RestRule kStrictRestRule{0.1, 0.1, 1, 60};

/// Drops copies of rigid parts (one or more part types) into an open bin with Bullet and runs
/// until they are at rest.
/// Bullet works in centimetres with 0.2 mm collision margins (hull pieces are shrunk by the
/// margin first), SimulationParams::solver_iterations contact-solver iterations per fixed step,
/// each started from the whole last step's impulses, whole contact manifolds from the first touch,
/// friction anchors (static friction: contact points held while inside the friction cone) and a
/// little angular damping; the two phases of SimulationParams: while falling, split-impulse
/// contacts at time_step_s (at the default 1/600 s a 6 mm plate does not tunnel), once landed,
/// contacts that leave a 0.01 mm overlap alone at rest_time_step_s, those of parts lying still
/// kept rather than searched again (StillContacts), and, in both phases, pairs of a hull piece
/// and another piece found apart not searched again until they may have moved (ConvexPairs);
/// penetrations stay far below 0.5 mm. The simulator is immutable after construction and may be
/// used from several threads at once; Simulate() builds a fresh world each call and keeps no
/// state between calls.
class PileSimulator {
 public:
  /// collision_pieces: convex pieces (mm, part frame) or empty to compute a convex decomposition
  /// of `part` with HACD, cached on disk in cache_dir keyed by mesh content + settings (a convex
  /// part uses its hull; an empty cache_dir disables the cache). `part` is in millimetres and must
  /// be closed and outward-wound: its volume and `physics.density_kg_m3` give the mass, centre of
  /// mass and inertia. Throws std::runtime_error naming the field at fault on bad input (sizes,
  /// densities, steps out of range; a part with no volume; flat collision pieces or pieces that do
  /// not span the part), or if the decomposition or its cache fails.
  PileSimulator(const TriangleMesh& part, const std::vector<TriangleMesh>& collision_pieces,
                const PartPhysics& physics, const BinSpec& bin, const SimulationParams& params,
                const std::string& cache_dir);

  /// As above for several part types (at least one); errors name the type by index
  /// ("part type 1: ...").
  PileSimulator(const std::vector<PartType>& types, const BinSpec& bin,
                const SimulationParams& params, const std::string& cache_dir);
  ~PileSimulator();
  PileSimulator(PileSimulator&&) noexcept;
  PileSimulator& operator=(PileSimulator&&) noexcept;

  /// Drops one part of type types[i] for each i, in that order, and runs until settled or
  /// max_sim_time_s. Pure function of (inputs, seed): bit-identical across runs and processes.
  /// All randomness from an engine seeded with `seed`: each part gets a rotation uniform over
  /// SO(3) and, with kRandomVolume, a random x, y that keeps its bounding box inside the opening.
  /// Parts are released at rest, their lowest point drop_height_mm above the rim. kRandomVolume
  /// releases them in quick waves: a part goes as soon as its bounding box there is free of the
  /// others (so none overlaps and none falls far). kSequential centres each on drop_point_mm and
  /// releases it once the previous one has landed (moved < 1 mm and < 2 degrees over 0.1 s, or
  /// 2 s passed). If the pile itself reaches the release height, parts go just above it. The
  /// landing rule's window starts after the last release. Throws std::runtime_error for an
  /// unknown type.
  PileResult Simulate(const std::vector<int>& types, uint64_t seed) const;

  /// As above; then, when `after` is not null, goes on as Resettle with a rule does (`rule` is
  /// not used without `after`). The result itself is the same as without (bit for bit).
  PileResult Simulate(const std::vector<int>& types, uint64_t seed, const RestRule& rule,
                      PileResult* after) const;

  /// `count` copies of type 0. Throws std::runtime_error if count < 0.
  PileResult Simulate(int count, uint64_t seed) const;

  /// Puts parts of types[i] at rest with their mesh frames at world_from_object[i] (mm; a pile
  /// Simulate settled, less what was picked from it) and runs until they settle again or
  /// max_sim_time_s, in Simulate's two phases (the landing rule's window starts at once) with its
  /// checks. Pure function of the inputs. Throws std::invalid_argument unless there is one pose per
  /// type.
  PileResult Resettle(const std::vector<int>& types,
                      const std::vector<Eigen::Isometry3d>& world_from_object) const;

  /// As above; then, when `after` is not null, goes on in the same world, every contact searched
  /// every step, until the pile is at rest by `rule` or rule.max_time_s more passed, and `after`
  /// gets the poses and checks then (settled: at rest by the rule; simulated_s: the time it went
  /// on). A strict check that a published pile was at rest: how far its parts still move. The
  /// result itself is the same as without (`rule` is not used without `after`). Throws
  /// std::invalid_argument as above, or for a rule whose values are not positive or whose window is
  /// longer than its cap.
  PileResult Resettle(const std::vector<int>& types,
                      const std::vector<Eigen::Isometry3d>& world_from_object, const RestRule& rule,
                      PileResult* after) const;

  /// The order in which a robot picking from above takes the parts of a pile (indices into
  /// `types`), the most visible part on top first: vertical rays on a 2 mm grid over the bin
  /// opening each count as seen for the part they meet first and as covered for the parts
  /// behind it; parts on top (covered on under 2 % of their rays) go before covered ones, and
  /// among those the most area seen from above first, then the higher centre of mass, then the
  /// lower index. Pure function of the inputs. Throws std::invalid_argument unless there is one
  /// pose per type.
  std::vector<int> PickOrder(const std::vector<int>& types,
                             const std::vector<Eigen::Isometry3d>& world_from_object) const;

  /// Lifts part `part` of a pile at rest (types and mesh frames as for Resettle) held at
  /// `point_mm` (a suction cup's contact, or the middle between two jaws' contacts) and pulled
  /// out along the unit `normal` (world, mm), in the pile's own world at rest (holding friction,
  /// rest_time_step_s): after 0.1 s for the contacts to take up the load, the hold (see
  /// LiftParams::Hold) rises lift_mm smoothly (3 x^2 - 2 x^3 over 1.5 lift_mm /
  /// lift_speed_mm_s: its top speed lift_speed_mm_s) and holds 0.3 s; it lets go when the force
  /// it needs exceeds what it holds with (Bullet's breaking impulse). The other parts move as
  /// the lift pushes and frees them. Pure function of the inputs. Throws std::invalid_argument
  /// for a part index out of range, one pose per type missing, a normal (or jaw axis) not of
  /// unit length or parameters out of range.
  LiftResult Lift(const std::vector<int>& types,
                  const std::vector<Eigen::Isometry3d>& world_from_object, int part,
                  const Eigen::Vector3d& point_mm, const Eigen::Vector3d& normal,
                  const LiftParams& lift) const;

  /// One line saying which collision shape type `type` uses, e.g. "compound of 4 convex pieces
  /// (supplied)" / "HACD decomposition, 7 pieces (cached, <file>)" / "convex hull (8 vertices)".
  std::string CollisionDescription(int type = 0) const;

  /// Mass of one part of type `type`, kg, from the mesh volume and the density.
  double mass_kg(int type = 0) const;

  /// The planar faces of the convex hull of type `type` (see HullFaces), for resting faces.
  const std::vector<HullFace>& hull_faces(int type = 0) const;

 private:
  struct Model;
  std::unique_ptr<const Model> model_;
};

}  // namespace stackgen
