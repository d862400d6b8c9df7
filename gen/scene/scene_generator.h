#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <stackgen/labels.hpp>
#include <stackgen/scene.hpp>

#include <Eigen/Geometry>

#include "gen/config/config.h"

namespace stackgen {

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

  /// Adds another scene's (or pile's) times and counts to these.
  void Add(const StageTimes& other);
};

/// The seed of scene `seq` of generator `generator_id` for base seed `base_seed`, after
/// `redraw` failed attempts: a SplitMix64 mix of all four, so nearby inputs give unrelated seeds.
uint64_t SceneSeed(uint64_t base_seed, int32_t generator_id, int64_t seq, int redraw);

/// The physics half of a scene: a settled pile and what was drawn for it. With
/// physics.views_per_pile V, pile k is shown by scenes k*V .. k*V+V-1.
struct SettledPile {
  int64_t pile = 0;
  /// The seed of the drop that settled (after redraws): the draws of its views derive from it.
  uint64_t seed = 0;
  /// The part type (config order) of each object.
  std::vector<int> object_types;
  /// Where each object settled, mm, its mesh frame in the bin (world) frame.
  std::vector<Eigen::Isometry3d> world_from_object;
  /// physics_ms and the redraws of this pile.
  StageTimes times;
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

  /// The physics of scene `seq`: drops and settles its pile (pile seq / views_per_pile),
  /// redrawing failed drops. Safe to call from any thread, also while Finish or Generate runs on
  /// another. Throws when max_redraws drops in a row fail.
  SettledPile Settle(int64_t seq) const;

  /// The rest of scene `seq`, a view of `pile` (which must be pile seq / views_per_pile):
  /// camera, lights and looks, render, labels, encoding. Call it from the thread that made the
  /// generator (it owns the GL context). Adds the times of these stages, not the pile's, to
  /// `times` when not null. Throws std::invalid_argument for a pile of another scene.
  scene Finish(const SettledPile& pile, int64_t seq, StageTimes* times);

  /// Finish in two stages: Render (camera, lights, looks, render and labels; on the thread that
  /// made the generator) and Encode (sensor effects and image encoding; safe on any thread, also
  /// while Render runs on another). Each adds its stages' times to `times` when not null.
  RenderedScene Render(const SettledPile& pile, int64_t seq, StageTimes* times);
  scene Encode(RenderedScene rendered, StageTimes* times) const;

  /// Scenes per pile (physics.views_per_pile).
  int views_per_pile() const;

  /// Lines describing the collision shape and the renderer in use.
  std::string Description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The labels of a scene: the same header, camera and instances, without images.
labels LabelsOf(const scene& scene);

}  // namespace stackgen
