#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <stackgen/labels.hpp>
#include <stackgen/model.hpp>
#include <stackgen/scene.hpp>

#include <Eigen/Geometry>

#include "gen/config/config.h"

namespace stackgen {

class PileSimulator;

/// Milliseconds spent per stage on one scene, and how often it was redrawn.
struct StageTimes {
  double physics_ms = 0;
  double render_ms = 0;
  double annotate_ms = 0;
  double encode_ms = 0;
  /// Drops that failed a check (unsettled, a part outside the bin, interpenetration) and were
  /// redrawn with a derived seed before this scene succeeded.
  int redraws = 0;
  /// Of those, the drops that did not settle in time, that left a part outside the bin, and
  /// that ended deeper than physics.max_penetration_mm (a drop may fail several checks).
  int redraws_unsettled = 0;
  int redraws_outside = 0;
  int redraws_penetrating = 0;
  /// Of physics_ms, the milliseconds spent on the drops that were redrawn, and on those of them
  /// that did not settle in time (not on the bus; stackgen-rest-check prints them).
  double redrawn_physics_ms = 0;
  double unsettled_physics_ms = 0;

  /// Adds another scene's (or pile's) times and counts to these.
  void Add(const StageTimes& other);
};

/// The seed of scene `seq` of generator `generator_id` for base seed `base_seed`, after
/// `redraw` failed attempts: a SplitMix64 mix of all four, so nearby inputs give unrelated seeds.
uint64_t SceneSeed(uint64_t base_seed, int32_t generator_id, int64_t seq, int redraw);

/// Where scene `seq` falls: pile, fill level and view. With physics.views_per_pile V, each
/// state of a pile is shown by V scenes in a row; with physics.pick_sequence, pile k of n parts
/// has the states (levels) 0 .. n, level l with l parts picked, so it makes (n + 1) * V scenes,
/// else only level 0.
struct ScenePlace {
  int64_t pile = 0;
  int level = 0;
  int view = 0;
  /// The first scene of this state (its view 0).
  int64_t first_seq = 0;
};

/// The physics half of a scene: one state of a settled pile and what was drawn for it.
struct SettledPile {
  int64_t pile = 0;
  /// Parts picked from the pile so far (physics.pick_sequence), 0 for the pile as dropped.
  int level = 0;
  /// The first scene that shows this state; scenes first_seq .. first_seq + V - 1 do.
  int64_t first_seq = 0;
  /// The seed of the drop that settled (after redraws).
  uint64_t drop_seed = 0;
  /// The seed the draws of this state's views derive from: drop_seed at level 0, a mix of it and
  /// the level after picks.
  uint64_t seed = 0;
  /// The part type (config order) of each object.
  std::vector<int> object_types;
  /// Where each object settled, mm, its mesh frame in the bin (world) frame.
  std::vector<Eigen::Isometry3d> world_from_object;
  /// physics_ms and the redraws of this state (a pick whose rest failed a check counts as a
  /// redraw).
  StageTimes times;
  /// After a pick: the index, among the previous state's parts, of the part picked; -1 at
  /// level 0. With grasps proven (grasps.prove_per_part), whether a suction grasp from above
  /// lifted it in the previous state's world (PileSimulator::Lift), and that grasp (world, mm;
  /// the normal the cup pulled along).
  int picked = -1;
  bool picked_proven = false;
  Eigen::Vector3d picked_point_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d picked_normal = Eigen::Vector3d::UnitZ();
};

/// The images of a rendered scene before the sensor and encoding (defined in the .cc).
struct RenderedImages;

/// A scene rendered and labelled whose images still need the sensor effects and encoding, the
/// last stage, which may run on another thread.
struct RenderedScene {
  /// Header, camera and instances; the images are empty.
  scene message;
  std::shared_ptr<RenderedImages> images;
};

/// Makes scenes: drops the part into the bin, renders the settled pile and labels it. Every
/// scene is a pure function of (config, base seed, generator id, seq). Generate is Settle then
/// Finish; a pipeline settles the next pile on another thread while scenes of this one are
/// finished.
class SceneGenerator {
 public:
  /// Loads the part's meshes, prepares collision shapes (decompositions cached in `cache_dir`)
  /// and the renderer. Throws naming the file or field when a mesh cannot be used or the bin is
  /// too small for the parts.
  SceneGenerator(const LoadedConfig& config, int32_t generator_id, uint64_t base_seed,
                 const std::string& cache_dir);
  ~SceneGenerator();

  /// Generates scene `seq` (header.utime is left 0 for the publisher to set). Adds the time of
  /// each stage to `times` when not null. Throws when max_redraws drops in a row fail.
  scene Generate(int64_t seq, StageTimes* times);

  /// The physics of scene `seq`: drops and settles its pile, redrawing failed drops, and with
  /// physics.pick_sequence picks parts from it down to the scene's level. Safe to call from any
  /// thread, also while Finish or Generate runs on another. Throws when max_redraws drops in a
  /// row fail, or when no part of a pile can be picked with the rest passing the checks.
  SettledPile Settle(int64_t seq) const;

  /// The state after `state`, the same as Settle of the first scene after its views but cheaper:
  /// the next part picked from it (physics.pick_sequence and parts left), else the next pile.
  /// Thread-safe as Settle.
  SettledPile SettleNext(const SettledPile& state) const;

  /// Where scene `seq` falls (see ScenePlace). Thread-safe. Throws std::invalid_argument for
  /// seq < 0.
  ScenePlace PlaceOf(int64_t seq) const;

  /// The rest of scene `seq`, a view of `pile` (which must be the state scene seq shows):
  /// camera, lights and looks, render, labels, encoding. Call it from the thread that made the
  /// generator (it owns the GL context). Adds the times of these stages, not the pile's, to
  /// `times` when not null. Throws std::invalid_argument for a state of another scene.
  scene Finish(const SettledPile& pile, int64_t seq, StageTimes* times);

  /// Finish in two stages: Render (camera, lights, looks, render and labels; on the thread that
  /// made the generator) and Encode (sensor effects and image encoding; safe on any thread, also
  /// while Render runs on another). Each adds its stages' times to `times` when not null.
  RenderedScene Render(const SettledPile& pile, int64_t seq, StageTimes* times);
  scene Encode(RenderedScene rendered, StageTimes* times) const;

  /// Scenes per state of a pile (physics.views_per_pile).
  int views_per_pile() const;
  /// Whether each state after a pile's first follows from the one before (physics.pick_sequence).
  bool pick_sequence() const;

  /// The pile simulator the scenes' physics runs on (for checks such as stackgen-rest-check).
  const PileSimulator& simulator() const;

  /// Lines describing the collision shape and the renderer in use.
  std::string Description() const;

  /// The model of each labelled class, by class id (header left for the publisher to set): the
  /// mesh of its first part type in millimetres, in the frame of the instances' poses, its
  /// diameter and the symmetries found from it (see FindSymmetries, gen/mesh/symmetry.h).
  const std::vector<model>& Models() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The labels of a scene: the same header, camera and instances, without images.
labels LabelsOf(const scene& scene);

/// Where collision decompositions are cached unless a --cache-dir says otherwise:
/// $XDG_CACHE_HOME/stackgen, else ~/.cache/stackgen, else /tmp/stackgen-cache.
std::string DefaultCacheDir();

}  // namespace stackgen
