#pragma once

// What the scene generator's own files share (scene_generator.cc, scene_setup.cc): its state
// (SceneGenerator::Impl) and each part type as a scene uses it. Not for use outside gen/scene/.

#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "gen/annotate/labels.h"
#include "gen/grasp/parallel_jaw.h"
#include "gen/grasp/suction.h"
#include "gen/physics/pile.h"
#include "gen/randomize/background.h"
#include "gen/randomize/camera_pose.h"
#include "gen/randomize/lighting.h"
#include "gen/randomize/surroundings.h"
#include "gen/render/renderer.h"
#include "gen/scene/scene_generator.h"

namespace stackgen {
namespace scene_internal {

using Clock = std::chrono::steady_clock;

inline double MillisecondsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// One part type of the config, as the scene uses it.
struct TypeInScene {
  int mesh_id = 0;
  // the configured material (for meshes without their own) and whether file materials are used
  Material material;
  bool use_file_materials = true;
  SurfaceDetail detail;  // physically based: its procedural detail
  // class id among the labelled types (1, 2, ... by first class_name), 0 = not labelled
  int class_id = 0;
  // grasps: its mesh among the grasp scene's, and its centre of mass (object frame)
  int grasp_mesh_id = -1;
  Eigen::Vector3d center_of_mass_mm = Eigen::Vector3d::Zero();
};

}  // namespace scene_internal

struct SceneGenerator::Impl {
  LoadedConfig loaded;
  int32_t generator_id = 0;
  uint64_t base_seed = 0;
  std::unique_ptr<PileSimulator> simulator;
  std::unique_ptr<Renderer> renderer;
  std::unique_ptr<BackgroundSource> backgrounds;
  std::vector<scene_internal::TypeInScene> types;
  int bin_mesh_id = 0;
  Material bin_material;
  SurfaceDetail bin_detail;
  // surroundings.table_probability: the table's quad (-1: none) and height, mm
  int floor_mesh_id = -1;
  double floor_z_mm = 0;
  // grasps: the scene's meshes for rays (the parts' and the bin's), used by Render only
  std::unique_ptr<GraspScene> grasp_scene;
  int grasp_bin_mesh_id = -1;
  // grasps: the meshes again, for the picks' own scenes (picks run on physics threads)
  std::vector<TriangleMesh> part_meshes;
  TriangleMesh bin_mesh;
  // physically based shading: the environments a scene draws from (renderer environment ids)
  std::vector<int> environment_ids;
  std::string description;
  // the model of each labelled class, index class_id - 1
  std::vector<model> models;
  // physics.pick_sequence: the first seq of piles 0, 1, ..., counted as far as asked
  std::mutex pile_starts_mutex;
  std::vector<int64_t> pile_starts = {0};

  const config::GeneratorConfig& config() const { return loaded.config; }

  // The part type of every object of a pile, drawn from `engine`: how many of each type, then
  // the types in config order.
  std::vector<int> ObjectTypes(std::mt19937_64& engine) const;
  // With picks: the object types of pile `pile`, those of its first drop.
  std::vector<int> PickedPileTypes(int64_t pile) const;
  // Drops and settles pile `pile_index` (its first scene is first_seq), redrawing failed drops.
  SettledPile Drop(int64_t pile_index, int64_t first_seq) const;
  // Picks the next part from `state` (see physics.pick_sequence); throws if none can go.
  void Pick(SettledPile* state, int views) const;
  // With proven grasps: `order` (PickOrder's) with the parts a suction grasp from above lifts
  // first, among the first grasps.prove_parts, and for each part so proven its grasp (in
  // `proven`, by part index; the others absent).
  std::vector<int> ProvenPickOrder(const SettledPile& state, const std::vector<int>& order,
                                   std::map<int, std::pair<Eigen::Vector3d, Eigen::Vector3d>>*
                                       proven) const;
  // the cup, the gripper and the lift of the config's grasps
  SuctionCup Cup() const;
  JawGripper Gripper() const;
  LiftParams LiftOf() const;
  // Whether a pile passes every check a published scene must pass; counts a failure in `times`.
  bool Passes(const PileResult& pile, StageTimes* times) const;
  // physics.drop_mode CUT_AND_PASTE: the parts placed at random, no physics, a pure function
  // of pile_seed
  PileResult PastedPile(const std::vector<int>& object_types, uint64_t pile_seed) const;
  // Physically based: draws an environment, its turn and strength into `options` (three draws
  // whatever the settings; used only when the config asks for PBR shading).
  void DrawEnvironment(std::mt19937_64& engine, RenderOptions* options) const;
  // Appends the bin and, physically based, the table or belt under it (instance id 0), styled
  // as `around` drew them.
  void AddSurroundings(const DrawnSurroundings& around, bool pbr, uint64_t seed,
                       std::vector<DrawItem>* items) const;
  // Appends the parts of `settled`: labelled ones get instance ids 1, 2, ... and an ObjectTruth
  // each; unlabelled distractors draw as 0, like the bin.
  void AddParts(const SettledPile& settled, const std::vector<MaterialGain>& gains, uint64_t seed,
                std::vector<DrawItem>* items, std::vector<ObjectTruth>* objects) const;

  // Setting up (scene_setup.cc): each part type's mesh, material and class in the renderer, and
  // its line of the description; the bin and the table under it; the environments.
  void AddPartTypes(const std::vector<PartType>& part_types,
                    const std::vector<std::string>& size_texts, std::ostringstream* description);
  void AddBinAndTable(const BinSpec& bin_spec);
  // grasps (suction or parallel_jaw): the meshes of the parts and the bin for the grasps' rays
  void AddGraspMeshes(const std::vector<PartType>& part_types, const BinSpec& bin_spec);
  // grasps: the ranked grasps of every annotated instance of `out` (its instances labelled
  // from `instance_map`, ids given in AddParts' order), seen by `camera`, appended to
  // out->suction_grasps and out->jaw_grasps. Not thread-safe (one grasp scene), as Render.
  void LabelGrasps(const SettledPile& settled, const CameraModel& camera,
                   const cv::Mat& instance_map, scene* out) const;
  // grasps.prove_per_part: lifts the best grasps of each kind of the topmost parts (PickOrder)
  // whose best grasp of that kind is clear in the pile's own physics and records what happened
  // in their messages; object_of: each part's object (its instance id; distractors above every
  // instance id)
  void ProveGrasps(const SettledPile& settled, const std::vector<int>& object_of,
                   const CameraModel& camera, scene* out) const;
  void AddEnvironments(std::ostringstream* description);

  // the camera's intrinsics from the config (a preset is resolved when the config is parsed).
  Intrinsics CameraIntrinsics() const {
    const config::CameraConfig& c = config().camera();
    const Eigen::Vector2d principal = PrincipalPoint(c);
    Intrinsics intrinsics;
    intrinsics.width = c.width();
    intrinsics.height = c.height();
    intrinsics.fx = c.fx();
    intrinsics.fy = c.fy();
    intrinsics.cx = principal.x();
    intrinsics.cy = principal.y();
    return intrinsics;
  }

  // the camera of one scene: the config's intrinsics and a pose drawn around the nominal one.
  CameraModel Camera(std::mt19937_64& engine) const {
    const Intrinsics intrinsics = CameraIntrinsics();
    CameraModel camera;
    static_cast<Intrinsics&>(camera) = intrinsics;
    camera.world_from_camera =
        SampleCameraPose(config().camera(), intrinsics, config().bin(), engine);
    // clip nothing in view: beyond the farthest camera, the bin's whole extent
    const config::BinConfig& bin = config().bin();
    camera.far_mm = std::max(
        camera.far_mm, 2 * (config().camera().height_mm() + config().camera().distance_jitter_mm() +
                            std::hypot(bin.inner_length_mm(), bin.inner_width_mm())));
    return camera;
  }
};

}  // namespace stackgen
