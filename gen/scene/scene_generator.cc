#include "gen/scene/scene_generator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <mutex>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <sstream>
#include <vector>

#include "contract/splitmix.h"
#include "gen/annotate/labels.h"
#include "gen/annotate/pose.h"
#include "gen/physics/pile.h"
#include "gen/randomize/background.h"
#include "gen/randomize/camera_pose.h"
#include "gen/randomize/depth_sensor.h"
#include "gen/randomize/lighting.h"
#include "gen/randomize/sensor.h"
#include "gen/randomize/surroundings.h"
#include "gen/randomize/uniform.h"
#include "gen/render/renderer.h"
#include "gen/scene/scene_generator_internal.h"

namespace stackgen {

using namespace scene_internal;

namespace {

// mixed into a pile's drop seed for the seeds of the states after picks
constexpr uint64_t kPickSalt = 0x7069636b5069636bULL;

// grasps: the suction scene's object of distractor i is this + i (labelled parts are their
// instance ids, below it; the bin is 0)
constexpr int kDistractorObject = 1000000;

// Each randomisation lever draws from an engine of its own, seeded from the scene seed and the
// lever, so switching one lever on or off never shifts another's draws.
enum class Lever : uint64_t {
  kCamera = 1,
  kLighting,
  kAppearance,
  kBackground,
  kSensor,
  kEnvironment,
  kSurroundings,
  kDepthSensor,
  kLightRadius,
};

std::mt19937_64 LeverEngine(uint64_t scene_seed, Lever lever) {
  return std::mt19937_64(SplitMixHash(SplitMixHash(scene_seed) ^ static_cast<uint64_t>(lever)));
}

// `detail` with the pattern of item `item` in the scene of `scene_seed`: each copy of a part
// and each scene shows another piece of the noise (a hash, no engine draw: nothing else moves)
SurfaceDetail PlacedDetail(SurfaceDetail detail, uint64_t scene_seed, uint64_t item) {
  const uint64_t h = SplitMixHash(SplitMixHash(scene_seed ^ 0x64657461696cULL) + item);
  for (int k = 0; k < 3; ++k) {
    detail.offset[k] = static_cast<float>((h >> (20 * k)) & 0xFFFFF) * (1000.f / 0x100000);
  }
  return detail;
}

// a number drawn uniformly from [lo, hi] (the same on every platform).
int UniformCount(std::mt19937_64& engine, int lo, int hi) {
  return lo + static_cast<int>(engine() % static_cast<uint64_t>(hi - lo + 1));
}

// turns an image into an image message, raw (little-endian rows) or PNG.
image EncodeImage(const cv::Mat& pixels, int8_t pixel_format,
                  config::OutputConfig::Encoding encoding) {
  image message;
  message.width = pixels.cols;
  message.height = pixels.rows;
  message.pixel_format = pixel_format;
  if (encoding == config::OutputConfig::PNG) {
    message.encoding = image::ENCODING_PNG;
    cv::Mat to_write = pixels;
    // OpenCV writes colour files from BGR.
    if (pixels.channels() == 3) cv::cvtColor(pixels, to_write, cv::COLOR_RGB2BGR);
    // colour (the camera's noise in every pixel) and ids (a few flat regions): OpenCV's default
    // when no level is given, the Sub filter at zlib level 1 with its run-length strategy, much
    // faster than level 1 with libpng's adaptive filters and no larger; depth (smooth slopes)
    // deflates far smaller with those filters (docs/results.md, "Speed")
    std::vector<int> parameters;
    if (pixel_format == image::PIXEL_DEPTH16) parameters = {cv::IMWRITE_PNG_COMPRESSION, 1};
    std::vector<uint8_t> bytes;
    if (!cv::imencode(".png", to_write, bytes, parameters)) {
      throw std::runtime_error("cannot encode a PNG image");
    }
    message.data = std::move(bytes);
  } else {
    message.encoding = image::ENCODING_RAW;
    const cv::Mat continuous = pixels.isContinuous() ? pixels : pixels.clone();
    const uint8_t* begin = continuous.ptr<uint8_t>(0);
    message.data.assign(begin, begin + continuous.total() * continuous.elemSize());
  }
  message.size = static_cast<int32_t>(message.data.size());
  return message;
}

// the nearest depth in `depth_mm` (CV_32FC1, 0 = nothing), or 0 when there is none
double NearestDepth(const cv::Mat& depth_mm) {
  float nearest = 0;
  for (int v = 0; v < depth_mm.rows; ++v) {
    const float* row = depth_mm.ptr<float>(v);
    for (int u = 0; u < depth_mm.cols; ++u) {
      if (row[u] > 0 && (nearest == 0 || row[u] < nearest)) nearest = row[u];
    }
  }
  return nearest;
}

// The scene message's camera: intrinsics, pose and the depth image's scale.
camera_info CameraMessage(const CameraModel& model, double depth_scale_mm) {
  camera_info out{};
  out.width = model.width;
  out.height = model.height;
  out.fx = model.fx;
  out.fy = model.fy;
  out.cx = model.cx;
  out.cy = model.cy;
  out.world_from_camera = ToPoseMessage(model.world_from_camera);
  out.depth_scale_mm = depth_scale_mm;
  return out;
}

}  // namespace

uint64_t SceneSeed(uint64_t base_seed, int32_t generator_id, int64_t seq, int redraw) {
  uint64_t seed = SplitMixHash(base_seed);
  seed = SplitMixHash(seed ^ static_cast<uint64_t>(static_cast<uint32_t>(generator_id)));
  seed = SplitMixHash(seed ^ static_cast<uint64_t>(seq));
  return SplitMixHash(seed ^ static_cast<uint64_t>(redraw));
}

SceneGenerator::~SceneGenerator() = default;

std::string SceneGenerator::Description() const { return impl_->description; }

const std::vector<model>& SceneGenerator::Models() const { return impl_->models; }

void StageTimes::Add(const StageTimes& other) {
  physics_ms += other.physics_ms;
  render_ms += other.render_ms;
  annotate_ms += other.annotate_ms;
  encode_ms += other.encode_ms;
  redraws += other.redraws;
  redraws_unsettled += other.redraws_unsettled;
  redraws_outside += other.redraws_outside;
  redraws_penetrating += other.redraws_penetrating;
  redrawn_physics_ms += other.redrawn_physics_ms;
  unsettled_physics_ms += other.unsettled_physics_ms;
}

int SceneGenerator::views_per_pile() const { return impl_->config().physics().views_per_pile(); }

bool SceneGenerator::pick_sequence() const { return impl_->config().physics().pick_sequence(); }

scene SceneGenerator::Generate(int64_t seq, StageTimes* times) {
  const SettledPile pile = Settle(seq);
  if (times != nullptr) times->Add(pile.times);
  return Finish(pile, seq, times);
}

ScenePlace SceneGenerator::PlaceOf(int64_t seq) const {
  if (seq < 0) throw std::invalid_argument("scene " + std::to_string(seq) + ": seq must be >= 0");
  const int views = views_per_pile();
  ScenePlace place;
  if (!impl_->config().physics().pick_sequence()) {
    place.pile = seq / views;
    place.view = static_cast<int>(seq % views);
    place.first_seq = seq - place.view;
    return place;
  }
  // with picks, pile k shows (n_k + 1) * V scenes: where the piles start, counted up to seq
  std::lock_guard<std::mutex> lock(impl_->pile_starts_mutex);
  std::vector<int64_t>& starts = impl_->pile_starts;
  while (starts.back() <= seq) {
    const int64_t pile = static_cast<int64_t>(starts.size()) - 1;
    const int64_t parts = static_cast<int64_t>(impl_->PickedPileTypes(pile).size());
    starts.push_back(starts.back() + (parts + 1) * views);
  }
  const auto next = std::upper_bound(starts.begin(), starts.end(), seq);
  place.pile = (next - starts.begin()) - 1;
  const int64_t offset = seq - *(next - 1);
  place.level = static_cast<int>(offset / views);
  place.view = static_cast<int>(offset % views);
  place.first_seq = seq - place.view;
  return place;
}

SettledPile SceneGenerator::Settle(int64_t seq) const {
  const ScenePlace place = PlaceOf(seq);
  SettledPile state = impl_->Drop(place.pile, place.first_seq - place.level * views_per_pile());
  StageTimes times = state.times;
  while (state.level < place.level) {
    impl_->Pick(&state, views_per_pile());
    times.Add(state.times);
  }
  state.times = times;
  return state;
}

SettledPile SceneGenerator::SettleNext(const SettledPile& state) const {
  const int views = views_per_pile();
  if (impl_->config().physics().pick_sequence() && !state.object_types.empty()) {
    SettledPile next = state;
    impl_->Pick(&next, views);
    return next;
  }
  const int64_t first_seq = state.first_seq + views;
  return impl_->Drop(PlaceOf(first_seq).pile, first_seq);
}

std::vector<int> SceneGenerator::Impl::ObjectTypes(std::mt19937_64& engine) const {
  // how many of each type, then the type of every object in config order
  std::vector<int> object_types;
  for (int t = 0; t < config().part_size(); ++t) {
    const config::PartConfig& part = config().part(t);
    const int count = part.count_max() > 0
                          ? UniformCount(engine, part.count_min(), part.count_max())
                          : part.count();
    object_types.insert(object_types.end(), count, t);
  }
  return object_types;
}

std::vector<int> SceneGenerator::Impl::PickedPileTypes(int64_t pile) const {
  std::mt19937_64 engine(SceneSeed(base_seed, generator_id, pile, 0));
  engine();  // the drop's seed
  return ObjectTypes(engine);
}

SettledPile SceneGenerator::Impl::Drop(int64_t pile_index, int64_t first_seq) const {
  const bool picks = config().physics().pick_sequence();
  SettledPile settled;
  settled.pile = pile_index;
  settled.first_seq = first_seq;
  StageTimes& local = settled.times;
  uint64_t& seed = settled.drop_seed;
  PileResult pile;
  std::vector<int>& object_types = settled.object_types;
  // with picks, the part counts of the first drop (where later piles start depends on them)
  const std::vector<int> pick_types = picks ? PickedPileTypes(pile_index) : std::vector<int>();

  // drop the parts; a drop that fails a check is redrawn with a derived seed.
  const Clock::time_point start = Clock::now();
  for (int redraw = 0;; ++redraw) {
    if (redraw > config().physics().max_redraws()) {
      throw std::runtime_error("scene " + std::to_string(first_seq) + ": " +
                               std::to_string(redraw) +
                               " drops in a row failed to settle inside the bin; check the "
                               "physics and bin settings");
    }
    seed = SceneSeed(base_seed, generator_id, pile_index, redraw);
    std::mt19937_64 physics_rng(seed);
    const uint64_t pile_seed = physics_rng();
    object_types = picks ? pick_types : ObjectTypes(physics_rng);
    if (config().physics().drop_mode() == config::PhysicsConfig::CUT_AND_PASTE) {
      pile = PastedPile(object_types, pile_seed);
      break;
    }
    const Clock::time_point drop_start = Clock::now();
    pile = simulator->Simulate(object_types, pile_seed);
    // every check a published scene must pass
    const int unsettled = local.redraws_unsettled;
    if (Passes(pile, &local)) break;
    const double drop_ms = MillisecondsSince(drop_start);
    local.redrawn_physics_ms += drop_ms;
    local.unsettled_physics_ms += local.redraws_unsettled > unsettled ? drop_ms : 0;
  }
  local.physics_ms = MillisecondsSince(start);
  settled.seed = seed;
  settled.world_from_object = std::move(pile.world_from_object);
  return settled;
}

PileResult SceneGenerator::Impl::PastedPile(const std::vector<int>& object_types,
                                            uint64_t pile_seed) const {
  // each part a uniform random orientation at a random place over the floor, 10..60 mm up: six
  // values per part, whatever the part
  std::mt19937_64 engine(pile_seed);
  const config::BinConfig& bin = config().bin();
  PileResult pile;
  pile.settled = true;
  for (size_t i = 0; i < object_types.size(); ++i) {
    const Eigen::Quaterniond rotation = UniformRotation(engine);
    const Eigen::Vector3d place(Uniform(engine, -0.5, 0.5) * bin.inner_length_mm(),
                                Uniform(engine, -0.5, 0.5) * bin.inner_width_mm(),
                                Uniform(engine, 10, 60));
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translate(place);
    pose.rotate(rotation);
    pile.world_from_object.push_back(pose);
  }
  return pile;
}

bool SceneGenerator::Impl::Passes(const PileResult& pile, StageTimes* times) const {
  const bool settled_ok = pile.settled;
  const bool inside = pile.num_outside == 0;
  const bool apart = pile.max_penetration_mm <= config().physics().max_penetration_mm();
  if (settled_ok && inside && apart) return true;
  ++times->redraws;
  // (a drop stops when a part falls out of the bin: unsettled says nothing more then)
  times->redraws_unsettled += settled_ok || !inside ? 0 : 1;
  times->redraws_outside += inside ? 0 : 1;
  times->redraws_penetrating += apart ? 0 : 1;
  return false;
}

void SceneGenerator::Impl::Pick(SettledPile* state, int views) const {
  const Clock::time_point start = Clock::now();
  StageTimes local;
  // the parts in the order a robot picks them; the first whose removal leaves a pile that
  // passes the checks goes
  std::vector<int> order = simulator->PickOrder(state->object_types, state->world_from_object);
  // with proven grasps, the parts a cup lifts go first
  std::map<int, std::pair<Eigen::Vector3d, Eigen::Vector3d>> proven;
  const config::GraspConfig& grasps = config().grasps();
  if (grasps.suction() && grasps.prove_per_part() > 0) {
    order = ProvenPickOrder(*state, order, &proven);
  }
  const int tries = std::min(static_cast<int>(order.size()), config().physics().max_redraws() + 1);
  for (int t = 0; t < tries; ++t) {
    std::vector<int> types = state->object_types;
    std::vector<Eigen::Isometry3d> poses = state->world_from_object;
    types.erase(types.begin() + order[t]);
    poses.erase(poses.begin() + order[t]);
    PileResult rest = simulator->Resettle(types, poses);
    if (!Passes(rest, &local)) continue;
    state->object_types = std::move(types);
    state->world_from_object = std::move(rest.world_from_object);
    state->picked = order[t];
    const auto grasp = proven.find(order[t]);
    state->picked_proven = grasp != proven.end();
    if (state->picked_proven) {
      state->picked_point_mm = grasp->second.first;
      state->picked_normal = grasp->second.second;
    }
    ++state->level;
    state->first_seq += views;
    state->seed = SplitMixHash(SplitMixHash(state->drop_seed ^ kPickSalt) +
                               static_cast<uint64_t>(state->level));
    local.physics_ms = MillisecondsSince(start);
    state->times = local;
    return;
  }
  throw std::runtime_error("scene " + std::to_string(state->first_seq + views) + " (pile " +
                           std::to_string(state->pile) + ", pick " +
                           std::to_string(state->level + 1) + "): none of the " +
                           std::to_string(tries) +
                           " parts tried could be picked with the rest settling inside the bin; "
                           "check the physics and bin settings");
}

struct RenderedImages {
  cv::Mat color;         // RGB8 (Phong)
  cv::Mat color_linear;  // linear RGB float (physically based)
  cv::Mat depth_mm;      // float
  cv::Mat instance;      // uint16 ids
  SensorEffects sensor;
  // with a 3D camera (sensor_3d): where its projector lights the surface, how much of the
  // pattern comes back, and the scene's seed for the sensor's own draws
  cv::Mat projector_visible;  // CV_8UC1
  cv::Mat projector_return;   // CV_32FC1
  uint64_t seed = 0;
};

void SceneGenerator::Impl::DrawEnvironment(std::mt19937_64& engine, RenderOptions* options) const {
  const config::RenderingConfig& rendering = config().rendering();
  const double environment_draw = Uniform(engine, 0, 1);
  const double yaw_deg = Uniform(engine, 0, 360);
  const double log_intensity =
      Uniform(engine, std::log(std::max(rendering.environment_intensity_min(), 1e-9)),
              std::log(std::max(rendering.environment_intensity_max(), 1e-9)));
  // (after the draws above, so that the environment's colour moves none of them)
  const double temperature = Uniform(engine, 0, 1);
  if (rendering.shading() != config::RenderingConfig::PBR) return;
  const config::LightingConfig& lighting = config().lighting();
  if (lighting.randomize() && lighting.color_temperature_max_k() > 0) {
    options->environment_color =
        BlackBodyColor(lighting.color_temperature_min_k() +
                       temperature * (lighting.color_temperature_max_k() -
                                      lighting.color_temperature_min_k()));
  }
  options->shading = Shading::kPbr;
  options->msaa_samples = rendering.msaa_samples();
  const size_t count = environment_ids.size();
  options->environment_id = environment_ids[std::min(
      count - 1, static_cast<size_t>(environment_draw * static_cast<double>(count)))];
  options->environment_yaw_deg = rendering.environment_random_yaw() ? yaw_deg : 0;
  options->environment_occlusion_mm = static_cast<float>(rendering.environment_occlusion_mm());
  options->environment_intensity =
      rendering.environment_intensity_max() > 0 ? static_cast<float>(std::exp(log_intensity)) : 0.f;
}

void SceneGenerator::Impl::AddSurroundings(const DrawnSurroundings& around, bool pbr, uint64_t seed,
                                           std::vector<DrawItem>* items) const {
  if (config().bin().visible()) {
    DrawItem bin_item;
    bin_item.mesh_id = bin_mesh_id;
    bin_item.instance_id = 0;
    bin_item.material = bin_material;
    bin_item.detail = bin_detail;
    if (pbr && around.bin_restyled) {
      bin_item.material.color = around.bin_color;
      bin_item.material.metal_color = around.bin_color;
      bin_item.material.metallic = around.bin_metallic;
      bin_item.material.roughness = around.bin_roughness;
    }
    if (pbr && around.bin_scuffed) {
      // a plastic tote also shows how it was moulded; a steel bin only wear
      const float metallic = bin_item.material.metallic;
      bin_item.detail.kind =
          metallic < 0.5f ? SurfaceDetail::Kind::kMoulded : SurfaceDetail::Kind::kScuffed;
      bin_item.detail.strength = around.bin_scuff_strength;
    }
    bin_item.detail = PlacedDetail(bin_item.detail, seed, 0);
    items->push_back(bin_item);
  }
  if (pbr && around.floor != DrawnSurroundings::Floor::kNone && floor_mesh_id >= 0) {
    DrawItem floor;
    floor.mesh_id = floor_mesh_id;
    floor.instance_id = 0;
    floor.world_from_object = Eigen::Translation3d(0, 0, floor_z_mm);
    floor.material.color = around.floor_color;
    floor.material.metal_color = around.floor_color;
    floor.material.metallic = around.floor_metallic;
    floor.material.roughness = around.floor_roughness;
    floor.material.specular = 0.5f;
    // a painted table is scuffed over centimetres; a belt has fine grooves along the bin's
    // length (x), a steel top coarser ones; wood has rings about 12 mm apart
    using Finish = DrawnSurroundings::Finish;
    const bool conveyor = around.floor == DrawnSurroundings::Floor::kConveyor;
    const bool brushed = conveyor || around.floor_finish == Finish::kMetal;
    floor.detail.kind = brushed                               ? SurfaceDetail::Kind::kBrushed
                        : around.floor_finish == Finish::kWood ? SurfaceDetail::Kind::kWood
                                                               : SurfaceDetail::Kind::kScuffed;
    floor.detail.strength = around.floor_detail_strength;
    floor.detail.scale_mm = conveyor                               ? 3.f
                            : around.floor_finish == Finish::kMetal ? 6.f
                            : around.floor_finish == Finish::kWood  ? 12.f
                                                                    : 20.f;
    floor.detail = PlacedDetail(floor.detail, seed, 1);
    floor.casts_shadow = false;
    items->push_back(floor);
  }
}

void SceneGenerator::Impl::AddParts(const SettledPile& settled,
                                    const std::vector<MaterialGain>& gains, uint64_t seed,
                                    std::vector<DrawItem>* items,
                                    std::vector<ObjectTruth>* objects) const {
  for (size_t i = 0; i < settled.world_from_object.size(); ++i) {
    const int t = settled.object_types[i];
    const config::PartConfig& part = config().part(t);
    const TypeInScene& type = types[t];
    DrawItem part_item;
    part_item.mesh_id = type.mesh_id;
    part_item.world_from_object = settled.world_from_object[i];
    part_item.material = type.material;
    part_item.use_mesh_materials = type.use_file_materials;
    part_item.gain = gains[t];
    part_item.detail = PlacedDetail(type.detail, seed, 2 + i);
    if (type.class_id > 0) {
      ObjectTruth object;
      object.instance_id = static_cast<int>(objects->size() + 1);
      object.class_id = type.class_id;
      object.class_name = part.class_name();
      object.world_from_object = settled.world_from_object[i];
      object.resting_face =
          RestingFace(simulator->hull_faces(t), settled.world_from_object[i].linear());
      objects->push_back(object);
      part_item.instance_id = static_cast<uint16_t>(object.instance_id);
    }
    items->push_back(part_item);
  }
}

SuctionCup SceneGenerator::Impl::Cup() const {
  const config::GraspConfig& grasps = config().grasps();
  SuctionCup cup;
  cup.diameter_mm = grasps.cup_diameter_mm();
  cup.compliance_mm = grasps.compliance_mm();
  cup.approach_mm = grasps.approach_mm();
  cup.tool_diameter_mm = grasps.tool_diameter_mm();
  cup.candidates_per_part = grasps.candidates_per_part();
  return cup;
}

JawGripper SceneGenerator::Impl::Gripper() const {
  const config::GraspConfig& grasps = config().grasps();
  JawGripper gripper;
  gripper.max_width_mm = grasps.jaw_max_width_mm();
  gripper.finger_width_mm = grasps.jaw_finger_width_mm();
  gripper.friction = grasps.jaw_friction();
  gripper.approach_mm = grasps.approach_mm();
  return gripper;
}

LiftParams SceneGenerator::Impl::LiftOf() const {
  const config::GraspConfig& grasps = config().grasps();
  LiftParams lift;
  lift.cup_diameter_mm = grasps.cup_diameter_mm();
  lift.vacuum_kpa = grasps.vacuum_kpa();
  lift.jaw_grip_force_n = grasps.jaw_grip_force_n();
  lift.jaw_friction = grasps.jaw_friction();
  lift.lift_mm = grasps.lift_mm();
  lift.lift_speed_mm_s = grasps.lift_speed_mm_s();
  return lift;
}

std::vector<int> SceneGenerator::Impl::ProvenPickOrder(
    const SettledPile& state, const std::vector<int>& order,
    std::map<int, std::pair<Eigen::Vector3d, Eigen::Vector3d>>* proven) const {
  const config::GraspConfig& grasps = config().grasps();
  const SuctionCup cup = Cup();
  const LiftParams lift = LiftOf();

  // the pile for rays (objects: part index + 1; the bin 0), its own: picks run on any physics
  // thread
  GraspScene scene;
  std::vector<int> mesh_of;
  for (const TriangleMesh& mesh : part_meshes) mesh_of.push_back(scene.AddMesh(mesh));
  scene.AddObject(scene.AddMesh(bin_mesh), Eigen::Isometry3d::Identity(), 0);
  for (size_t i = 0; i < state.world_from_object.size(); ++i) {
    scene.AddObject(mesh_of[static_cast<size_t>(state.object_types[i])],
                    state.world_from_object[i], static_cast<int>(i) + 1);
  }

  // the first prove_parts parts from the top: each whose best suction grasps from above (clear
  // ones) lift it goes first, in the same order
  std::vector<int> first, rest;
  for (size_t k = 0; k < order.size(); ++k) {
    const int part = order[k];
    bool lifted = false;
    if (static_cast<int>(k) < grasps.prove_parts()) {
      const Eigen::Vector3d com =
          state.world_from_object[static_cast<size_t>(part)] *
          types[static_cast<size_t>(state.object_types[static_cast<size_t>(part)])]
              .center_of_mass_mm;
      const std::vector<SuctionGrasp> found = SuctionGrasps(
          scene, scene.PointsFromAbove(part + 1, cup.candidates_per_part), part + 1, com, cup);
      for (size_t g = 0; g < found.size() && static_cast<int>(g) < grasps.prove_per_part(); ++g) {
        if (!found[g].approach_clear) break;
        const LiftResult result = simulator->Lift(state.object_types, state.world_from_object,
                                                  part, found[g].point_mm, found[g].normal, lift);
        if (result.outcome == LiftResult::Outcome::kLifted) {
          (*proven)[part] = {found[g].point_mm, found[g].normal};
          lifted = true;
          break;
        }
      }
    }
    (lifted ? first : rest).push_back(part);
  }
  first.insert(first.end(), rest.begin(), rest.end());
  return first;
}

namespace {

// a world-frame point or direction of a grasp as a message's camera-frame array
void ToCameraFrame(const Eigen::Vector3d& world, const Eigen::Isometry3d& camera_from_world,
                   bool direction, double* out) {
  const Eigen::Vector3d camera =
      direction ? Eigen::Vector3d(camera_from_world.linear() * world) : camera_from_world * world;
  for (int k = 0; k < 3; ++k) out[k] = camera[k];
}

// a camera-frame array of a message as a world-frame point or direction
Eigen::Vector3d ToWorldFrame(const double* camera, const Eigen::Isometry3d& world_from_camera,
                             bool direction) {
  const Eigen::Vector3d value(camera[0], camera[1], camera[2]);
  return direction ? Eigen::Vector3d(world_from_camera.linear() * value)
                   : Eigen::Vector3d(world_from_camera * value);
}

// what a lift did, into a grasp message's proof fields; object_of names the parts (labelled
// ones below kDistractorObject)
template <typename Grasp>
void RecordProof(const LiftResult& result, const std::vector<int>& object_of, Grasp* grasp) {
  grasp->proof = result.outcome == LiftResult::Outcome::kLifted    ? suction_grasp::PROOF_LIFTED
                 : result.outcome == LiftResult::Outcome::kDropped ? suction_grasp::PROOF_DROPPED
                                                                   : suction_grasp::PROOF_STUCK;
  grasp->proof_swing_deg = result.swing_deg;
  // the labelled parts that moved more than 1 mm, most first
  std::vector<std::pair<double, int32_t>> moved;
  double most = 0;
  for (size_t i = 0; i < result.moved_mm.size(); ++i) {
    most = std::max(most, result.moved_mm[i]);
    if (result.moved_mm[i] > 1 && object_of[i] < kDistractorObject) {
      moved.emplace_back(-result.moved_mm[i], object_of[i]);
    }
  }
  std::sort(moved.begin(), moved.end());
  grasp->proof_neighbours_moved_mm = most;
  grasp->num_moved = static_cast<int32_t>(moved.size());
  for (size_t m = 0; m < moved.size() && m < 8; ++m) {
    grasp->moved_instance_ids[m] = moved[m].second;
  }
}

// the grasps of `instance_id` among `all`, by rank
template <typename Grasp>
std::vector<Grasp*> GraspsOf(std::vector<Grasp>& all, int instance_id) {
  std::vector<Grasp*> own;
  for (Grasp& grasp : all) {
    if (grasp.instance_id == instance_id) own.push_back(&grasp);
  }
  std::sort(own.begin(), own.end(),
            [](const Grasp* a, const Grasp* b) { return a->rank < b->rank; });
  return own;
}

}  // namespace

void SceneGenerator::Impl::LabelGrasps(const SettledPile& settled, const CameraModel& camera,
                                       const cv::Mat& instance_map, scene* out) const {
  const config::GraspConfig& grasps = config().grasps();
  const SuctionCup cup = Cup();
  const JawGripper gripper = Gripper();

  // the scene for rays: the bin (object 0), the parts by instance id (distractors above them)
  grasp_scene->ClearObjects();
  grasp_scene->AddObject(grasp_bin_mesh_id, Eigen::Isometry3d::Identity(), 0);
  std::vector<int> object_of(settled.world_from_object.size());
  int next_instance = 1;
  for (size_t i = 0; i < settled.world_from_object.size(); ++i) {
    const TypeInScene& type = types[settled.object_types[i]];
    object_of[i] = type.class_id > 0 ? next_instance++ : kDistractorObject + static_cast<int>(i);
    grasp_scene->AddObject(type.grasp_mesh_id, settled.world_from_object[i], object_of[i]);
  }

  // each annotated instance's grasps from the points the camera sees, best first, in the
  // camera frame
  const Eigen::Isometry3d camera_from_world = camera.world_from_camera.inverse();
  for (const instance& labelled : out->instances) {
    if (!labelled.annotated) continue;
    const auto part = std::find(object_of.begin(), object_of.end(), labelled.instance_id);
    if (part == object_of.end()) continue;
    const size_t i = static_cast<size_t>(part - object_of.begin());
    const Eigen::Vector3d com =
        settled.world_from_object[i] * types[settled.object_types[i]].center_of_mass_mm;
    const std::vector<SurfacePoint> contacts =
        grasp_scene->SeenPoints(camera, instance_map, labelled.instance_id, labelled.instance_id,
                                grasps.candidates_per_part());
    if (grasps.suction()) {
      const std::vector<SuctionGrasp> found =
          SuctionGrasps(*grasp_scene, contacts, labelled.instance_id, com, cup);
      for (size_t rank = 0; rank < found.size(); ++rank) {
        const SuctionGrasp& grasp = found[rank];
        suction_grasp message{};
        message.instance_id = labelled.instance_id;
        message.rank = static_cast<int32_t>(rank);
        ToCameraFrame(grasp.point_mm, camera_from_world, false, message.point_mm);
        ToCameraFrame(grasp.normal, camera_from_world, true, message.normal);
        message.u = grasp.u;
        message.v = grasp.v;
        message.seal = grasp.seal;
        message.clearance_mm = grasp.clearance_mm;
        message.approach_clear = grasp.approach_clear;
        message.com_offset_mm = grasp.com_offset_mm;
        message.proof = suction_grasp::PROOF_NOT_TRIED;
        out->suction_grasps.push_back(message);
      }
    }
    if (grasps.parallel_jaw()) {
      const std::vector<JawGrasp> found =
          JawGrasps(*grasp_scene, contacts, labelled.instance_id, com,
                    camera.world_from_camera.translation(), gripper);
      for (size_t rank = 0; rank < found.size(); ++rank) {
        const JawGrasp& grasp = found[rank];
        jaw_grasp message{};
        message.instance_id = labelled.instance_id;
        message.rank = static_cast<int32_t>(rank);
        ToCameraFrame(grasp.point_a_mm, camera_from_world, false, message.point_a_mm);
        ToCameraFrame(grasp.point_b_mm, camera_from_world, false, message.point_b_mm);
        ToCameraFrame(grasp.approach, camera_from_world, true, message.approach);
        message.u = grasp.u;
        message.v = grasp.v;
        message.width_mm = grasp.width_mm;
        message.cone_margin_deg = grasp.cone_margin_deg;
        message.clearance_mm = grasp.clearance_mm;
        message.approach_clear = grasp.approach_clear;
        message.com_offset_mm = grasp.com_offset_mm;
        message.proof = suction_grasp::PROOF_NOT_TRIED;
        out->jaw_grasps.push_back(message);
      }
    }
  }
  out->num_suction_grasps = static_cast<int32_t>(out->suction_grasps.size());
  out->num_jaw_grasps = static_cast<int32_t>(out->jaw_grasps.size());
  if (grasps.prove_per_part() > 0) ProveGrasps(settled, object_of, camera, out);
}

void SceneGenerator::Impl::ProveGrasps(const SettledPile& settled,
                                       const std::vector<int>& object_of,
                                       const CameraModel& camera, scene* out) const {
  const config::GraspConfig& grasps = config().grasps();
  const std::vector<int> order =
      simulator->PickOrder(settled.object_types, settled.world_from_object);
  const Eigen::Isometry3d& world_from_camera = camera.world_from_camera;
  const auto lift = [&](int part, const Eigen::Vector3d& point, const Eigen::Vector3d& pull,
                        const LiftParams& params) {
    return simulator->Lift(settled.object_types, settled.world_from_object, part, point,
                           pull.normalized(), params);
  };

  // each kind: the parts from the top down (as a robot picks) whose best grasp of the kind is
  // clear, their best grasps lifted in the pile as it was published
  int proven_parts = 0;
  for (const int part : order) {
    if (proven_parts >= grasps.prove_parts()) break;
    std::vector<suction_grasp*> own = GraspsOf(out->suction_grasps, object_of[part]);
    if (own.empty() || !own.front()->approach_clear) continue;
    ++proven_parts;
    const LiftParams cup = LiftOf();
    for (size_t k = 0; k < own.size() && static_cast<int>(k) < grasps.prove_per_part(); ++k) {
      suction_grasp& grasp = *own[k];
      RecordProof(lift(part, ToWorldFrame(grasp.point_mm, world_from_camera, false),
                       ToWorldFrame(grasp.normal, world_from_camera, true), cup),
                  object_of, &grasp);
    }
  }
  proven_parts = 0;
  for (const int part : order) {
    if (proven_parts >= grasps.prove_parts()) break;
    std::vector<jaw_grasp*> own = GraspsOf(out->jaw_grasps, object_of[part]);
    if (own.empty() || !own.front()->approach_clear) continue;
    ++proven_parts;
    for (size_t k = 0; k < own.size() && static_cast<int>(k) < grasps.prove_per_part(); ++k) {
      jaw_grasp& grasp = *own[k];
      const Eigen::Vector3d a = ToWorldFrame(grasp.point_a_mm, world_from_camera, false);
      const Eigen::Vector3d b = ToWorldFrame(grasp.point_b_mm, world_from_camera, false);
      LiftParams jaws = LiftOf();
      jaws.hold = LiftParams::Hold::kJaws;
      jaws.jaw_axis = (b - a).normalized();
      RecordProof(lift(part, (a + b) / 2, -ToWorldFrame(grasp.approach, world_from_camera, true),
                       jaws),
                  object_of, &grasp);
    }
  }
}

scene SceneGenerator::Finish(const SettledPile& settled, int64_t seq, StageTimes* times) {
  return Encode(Render(settled, seq, times), times);
}

RenderedScene SceneGenerator::Render(const SettledPile& settled, int64_t seq, StageTimes* times) {
  const config::GeneratorConfig& config = impl_->config();
  if (seq < settled.first_seq || seq >= settled.first_seq + views_per_pile()) {
    const ScenePlace place = PlaceOf(seq);
    throw std::invalid_argument(
        "scene " + std::to_string(seq) + " shows pile " + std::to_string(place.pile) + " after " +
        std::to_string(place.level) + " picks, not pile " + std::to_string(settled.pile) +
        " after " + std::to_string(settled.level));
  }
  StageTimes local;
  // the seed of this view: the state's for view 0 (a single view draws what it always drew),
  // a mix of it and the view's index for the others
  const int64_t view = seq - settled.first_seq;
  const uint64_t seed =
      view == 0 ? settled.seed
                : SplitMixHash(settled.seed ^ SplitMixHash(static_cast<uint64_t>(view)));

  // the scene's look, each lever from its own engine: camera, lights, backgrounds, materials.
  std::mt19937_64 camera_engine = LeverEngine(seed, Lever::kCamera);
  std::mt19937_64 lighting_engine = LeverEngine(seed, Lever::kLighting);
  std::mt19937_64 appearance_engine = LeverEngine(seed, Lever::kAppearance);
  std::mt19937_64 background_engine = LeverEngine(seed, Lever::kBackground);
  std::mt19937_64 sensor_engine = LeverEngine(seed, Lever::kSensor);
  std::mt19937_64 environment_engine = LeverEngine(seed, Lever::kEnvironment);
  Clock::time_point start = Clock::now();
  const CameraModel camera = impl_->Camera(camera_engine);
  std::vector<Light> lights = SampleLights(config.lighting(), lighting_engine);
  // the lamps' sizes; a ring light stays a point: its shadows fall behind the parts, out of
  // the camera's sight
  std::mt19937_64 light_radius_engine = LeverEngine(seed, Lever::kLightRadius);
  DrawLightRadii(config.lighting(), light_radius_engine, &lights);
  if (const auto ring = SampleCameraLight(config.lighting(),
                                          camera.world_from_camera.translation(), lighting_engine)) {
    lights.push_back(*ring);
  }
  RenderOptions options;
  options.background_image =
      impl_->backgrounds->Draw(camera.width, camera.height, background_engine);
  options.shadows = config.lighting().shadows();
  options.shadow_map_size = config.lighting().shadow_map_size();
  impl_->DrawEnvironment(environment_engine, &options);
  const config::Sensor3dConfig& sensor_3d = config.sensor_3d();
  if (sensor_3d.enabled()) {
    options.projector_return = true;
    options.projector_position_mm =
        camera.world_from_camera * Eigen::Vector3d(sensor_3d.baseline_mm(), 0, 0);
  }
  // one gain per part type: the copies of a type look alike, like one batch of parts
  std::vector<MaterialGain> gains;
  for (int t = 0; t < config.part_size(); ++t) {
    gains.push_back(SampleMaterialGain(config.appearance(), appearance_engine));
  }

  // physically based: the surroundings of this scene (always drawn, used only then)
  std::mt19937_64 surroundings_engine = LeverEngine(seed, Lever::kSurroundings);
  const DrawnSurroundings around = SampleSurroundings(config.surroundings(), surroundings_engine);
  const bool pbr = options.shading == Shading::kPbr;

  // render the bin and the parts (instance ids 1..N), then each part alone.
  std::vector<DrawItem> items;
  impl_->AddSurroundings(around, pbr, seed, &items);
  std::vector<ObjectTruth> objects;
  impl_->AddParts(settled, gains, seed, &items, &objects);
  RenderResult rendered = impl_->renderer->Render(camera, lights, options, items);
  cv::Mat projector_visible;
  if (sensor_3d.enabled()) {
    // the 3D camera's projector: what it lights, from its depth image (an unlit pass from its
    // pose holding everything the camera sees from the nearest surface on)
    const double nearest = NearestDepth(rendered.depth_mm);
    if (nearest > 0) {
      const CameraModel projector =
          ProjectorCamera(camera, sensor_3d.baseline_mm(), nearest);
      RenderOptions unlit;
      const RenderResult seen = impl_->renderer->Render(projector, {}, unlit, items);
      projector_visible = ProjectorVisible(rendered.depth_mm, camera, seen.depth_mm, projector,
                                           sensor_3d.baseline_mm());
    } else {
      projector_visible = cv::Mat(rendered.depth_mm.size(), CV_8UC1, cv::Scalar(0));
    }
  }
  std::vector<cv::Mat> silhouettes, beyond;
  impl_->renderer->RenderSilhouettes(camera, items, &silhouettes, &beyond);
  local.render_ms = MillisecondsSince(start);

  // label every object from the same render.
  start = Clock::now();
  scene out{};
  out.header.seq = seq;
  out.header.generator_id = impl_->generator_id;
  out.header.seed = static_cast<int64_t>(seed);
  out.header.utime = 0;
  out.camera = CameraMessage(camera, config.camera().depth_scale_mm());
  out.instances =
      LabelInstances(rendered.instance, silhouettes, beyond, objects, camera.world_from_camera,
                     config.annotation().min_visib_fract(),
                     config.annotation().occlusion_rule() == config::AnnotationConfig::IGNORE,
                     config.annotation().min_visible_px());
  out.num_instances = static_cast<int32_t>(out.instances.size());
  if (config.grasps().suction() || config.grasps().parallel_jaw()) {
    impl_->LabelGrasps(settled, camera, rendered.instance, &out);
  }
  local.annotate_ms = MillisecondsSince(start);

  // what the encoding stage needs: the images and this scene's sensor draw
  auto images = std::make_shared<RenderedImages>();
  images->color = rendered.color;
  images->color_linear = rendered.color_linear;
  images->depth_mm = rendered.depth_mm;
  images->instance = rendered.instance;
  images->sensor = SampleSensorEffects(config.sensor(), sensor_engine);
  images->projector_visible = projector_visible;
  images->projector_return = rendered.projector_return;
  images->seed = seed;
  if (times != nullptr) times->Add(local);
  return RenderedScene{std::move(out), std::move(images)};
}

scene SceneGenerator::Encode(RenderedScene rendered_scene, StageTimes* times) const {
  const config::GeneratorConfig& config = impl_->config();
  RenderedImages& rendered = *rendered_scene.images;
  scene out = std::move(rendered_scene.message);
  StageTimes local;

  // the camera's sensor on the final image (gray or colour), never on depth or ids; then encode
  // the images: colour or gray, depth in depth_scale units, instance ids.
  const Clock::time_point start = Clock::now();
  const config::OutputConfig::Encoding encoding = config.output().image_encoding();
  // (the sensor works on the rendered colour image itself: nothing else reads it)
  cv::Mat picture;
  if (!rendered.color_linear.empty()) {
    // physically based: exposure, noise and the tone curve in the camera's order
    picture =
        DevelopLinearImage(rendered.sensor, rendered.color_linear, config.camera().grayscale());
  } else {
    picture = rendered.color;
    if (config.camera().grayscale()) cv::cvtColor(rendered.color, picture, cv::COLOR_RGB2GRAY);
    ApplySensorEffects(rendered.sensor, &picture);
  }
  out.color = EncodeImage(
      picture, config.camera().grayscale() ? image::PIXEL_GRAY8 : image::PIXEL_RGB8, encoding);
  cv::Mat depth;
  rendered.depth_mm.convertTo(depth, CV_16U, 1.0 / config.camera().depth_scale_mm());
  out.depth = EncodeImage(depth, image::PIXEL_DEPTH16, encoding);
  out.instance_map = EncodeImage(rendered.instance, image::PIXEL_INSTANCE16, encoding);
  if (!rendered.projector_visible.empty()) {
    // the 3D camera's depth, from its own engine
    std::mt19937_64 depth_engine = LeverEngine(rendered.seed, Lever::kDepthSensor);
    const cv::Mat measured =
        SensorDepth(rendered.depth_mm, rendered.projector_visible, rendered.projector_return,
                    DepthSensorOf(config.sensor_3d()), depth_engine);
    cv::Mat counts;
    measured.convertTo(counts, CV_16U, 1.0 / config.camera().depth_scale_mm());
    out.depth_sensor = EncodeImage(counts, image::PIXEL_DEPTH16, encoding);
  }
  local.encode_ms = MillisecondsSince(start);

  if (times != nullptr) times->Add(local);
  return out;
}

labels LabelsOf(const scene& scene) {
  labels out;
  out.header = scene.header;
  out.camera = scene.camera;
  out.num_instances = scene.num_instances;
  out.instances = scene.instances;
  out.num_suction_grasps = scene.num_suction_grasps;
  out.suction_grasps = scene.suction_grasps;
  out.num_jaw_grasps = scene.num_jaw_grasps;
  out.jaw_grasps = scene.jaw_grasps;
  return out;
}

const PileSimulator& SceneGenerator::simulator() const { return *impl_->simulator; }

std::string DefaultCacheDir() {
  const char* xdg = std::getenv("XDG_CACHE_HOME");
  if (xdg != nullptr && xdg[0] != '\0') return std::string(xdg) + "/stackgen";
  const char* home = std::getenv("HOME");
  if (home != nullptr && home[0] != '\0') return std::string(home) + "/.cache/stackgen";
  return "/tmp/stackgen-cache";
}

}  // namespace stackgen
