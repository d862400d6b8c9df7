#include "gen/scene/scene_generator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <mutex>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <sstream>
#include <vector>

#include "bus/splitmix.h"
#include "gen/annotate/labels.h"
#include "gen/annotate/pose.h"
#include "gen/mesh/mesh.h"
#include "gen/mesh/symmetry.h"
#include "gen/physics/pile.h"
#include "gen/randomize/background.h"
#include "gen/randomize/camera_pose.h"
#include "gen/randomize/lighting.h"
#include "gen/randomize/sensor.h"
#include "gen/randomize/surroundings.h"
#include "gen/randomize/uniform.h"
#include "gen/render/renderer.h"

namespace stackgen {
namespace {

using Clock = std::chrono::steady_clock;

double MillisecondsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// mixed into a pile's drop seed for the seeds of the states after picks
constexpr uint64_t kPickSalt = 0x7069636b5069636bULL;

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
};

std::mt19937_64 LeverEngine(uint64_t scene_seed, Lever lever) {
  return std::mt19937_64(SplitMixHash(SplitMixHash(scene_seed) ^ static_cast<uint64_t>(lever)));
}

// The renderer's surface detail of a config's kind, strength and feature size.
SurfaceDetail DetailOf(config::SurfaceDetail::Kind kind, double strength, double scale_mm) {
  SurfaceDetail detail;
  detail.kind = kind == config::SurfaceDetail::CAST      ? SurfaceDetail::Kind::kCast
                : kind == config::SurfaceDetail::BRUSHED ? SurfaceDetail::Kind::kBrushed
                : kind == config::SurfaceDetail::SCUFFED ? SurfaceDetail::Kind::kScuffed
                : kind == config::SurfaceDetail::MOULDED ? SurfaceDetail::Kind::kMoulded
                                                         : SurfaceDetail::Kind::kNone;
  detail.strength = static_cast<float>(strength);
  detail.scale_mm = static_cast<float>(scale_mm);
  return detail;
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

// A part shorter than this across, in pixels at the camera's nominal distance, cannot be
// labelled usefully; nor one whose longest side is below 1/kMinPartFractionOfBin of the bin floor's
// short side (a mesh in metres read as millimetres is both).
constexpr double kMinPartPixels = 8;
constexpr double kMinPartFractionOfBin = 100;

// The likely unit of a mesh whose longest side `longest` (in the config's mm) is implausible for
// a bin with floor sides `floor_short` <= `floor_long`: the hint for its error.
std::string ScaleHint(double longest, double scale_to_mm, double floor_short, double floor_long) {
  struct Unit {
    const char* name;
    double factor;
  };
  for (const Unit unit : {Unit{"metres", 1000}, Unit{"inches", 25.4}, Unit{"centimetres", 10}}) {
    const double scaled = longest * unit.factor;
    if (scaled >= floor_short / 20 && scaled <= floor_long) {
      std::ostringstream text;
      text << "a mesh in " << unit.name << " needs scale_to_mm: " << unit.factor * scale_to_mm
           << " in its part block";
      return text.str();
    }
  }
  std::ostringstream text;
  text << "scale_to_mm (now " << scale_to_mm << ") is the factor from the mesh's units to mm";
  return text.str();
}

// a length in pixels: "142", or "0.071" (two significant digits) below 10
std::string PixelsText(double pixels) {
  std::ostringstream text;
  if (pixels >= 10) {
    text << std::fixed << std::setprecision(0) << pixels;
  } else {
    text << std::setprecision(2) << pixels;
  }
  return text.str();
}

// "80.0 x 40.0 x 10.0 mm, 142 px across at 450 mm": a part's sides (shortest first) and its
// longest side's length in the image, `pixels`, at the camera's nominal distance.
std::string PartSizeText(const Eigen::Vector3d& sides, double pixels, double distance_mm) {
  std::ostringstream text;
  text << std::fixed << std::setprecision(1) << sides[2] << " x " << sides[1] << " x " << sides[0]
       << " mm, " << std::setprecision(0) << pixels << " px across at " << distance_mm << " mm";
  return text.str();
}

// a number drawn uniformly from [lo, hi] (the same on every platform).
int UniformCount(std::mt19937_64& engine, int lo, int hi) {
  return lo + static_cast<int>(engine() % static_cast<uint64_t>(hi - lo + 1));
}

// "60 x 40 x 10 mm": the sides of a box, longest first.
std::string SizeText(const Eigen::Vector3d& sides) {
  std::ostringstream text;
  text << sides[2] << " x " << sides[1] << " x " << sides[0] << " mm";
  return text.str();
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
    std::vector<uint8_t> bytes;
    if (!cv::imencode(".png", to_write, bytes, {cv::IMWRITE_PNG_COMPRESSION, 1})) {
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

}  // namespace

uint64_t SceneSeed(uint64_t base_seed, int32_t generator_id, int64_t seq, int redraw) {
  uint64_t seed = SplitMixHash(base_seed);
  seed = SplitMixHash(seed ^ static_cast<uint64_t>(static_cast<uint32_t>(generator_id)));
  seed = SplitMixHash(seed ^ static_cast<uint64_t>(seq));
  return SplitMixHash(seed ^ static_cast<uint64_t>(redraw));
}

// The model message of class `class_id`, whose first part type is `part` with mesh `mesh` (mm).
model ModelOf(const TriangleMesh& mesh, int class_id, const config::PartConfig& part) {
  model out{};
  out.class_id = class_id;
  out.class_name = part.class_name();
  out.mesh = part.mesh();
  out.num_vertices = static_cast<int32_t>(mesh.positions_mm.size());
  for (size_t v = 0; v < mesh.positions_mm.size(); ++v) {
    const Eigen::Vector3f& p = mesh.positions_mm[v];
    const Eigen::Vector3f& n = mesh.normals[v];
    out.vertices_mm.push_back({p.x(), p.y(), p.z()});
    out.normals.push_back({n.x(), n.y(), n.z()});
  }
  out.num_triangles = static_cast<int32_t>(mesh.triangles.size());
  for (const std::array<uint32_t, 3>& triangle : mesh.triangles) {
    out.triangles.push_back({static_cast<int32_t>(triangle[0]), static_cast<int32_t>(triangle[1]),
                             static_cast<int32_t>(triangle[2])});
  }
  // symmetries within 1 % of the diameter: a machined part's chamfers and holes count, the
  // tessellation of a round part does not
  out.diameter_mm = MeshDiameter(mesh);
  const MeshSymmetries symmetries = FindSymmetries(mesh, 0.01 * out.diameter_mm);
  for (const Eigen::Matrix4d& transform : symmetries.discrete) {
    std::vector<double> row_major(16);
    for (int i = 0; i < 16; ++i) row_major[i] = transform(i / 4, i % 4);
    out.discrete_symmetries.push_back(std::move(row_major));
  }
  out.num_discrete_symmetries = static_cast<int32_t>(out.discrete_symmetries.size());
  for (const ContinuousSymmetry& symmetry : symmetries.continuous) {
    out.continuous_axes.push_back({symmetry.axis.x(), symmetry.axis.y(), symmetry.axis.z()});
    out.continuous_offsets_mm.push_back(
        {symmetry.offset_mm.x(), symmetry.offset_mm.y(), symmetry.offset_mm.z()});
  }
  out.num_continuous_symmetries = static_cast<int32_t>(out.continuous_axes.size());
  return out;
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
};

struct SceneGenerator::Impl {
  LoadedConfig loaded;
  int32_t generator_id = 0;
  uint64_t base_seed = 0;
  std::unique_ptr<PileSimulator> simulator;
  std::unique_ptr<Renderer> renderer;
  std::unique_ptr<BackgroundSource> backgrounds;
  std::vector<TypeInScene> types;
  int bin_mesh_id = 0;
  Material bin_material;
  SurfaceDetail bin_detail;
  // surroundings.table_probability: the table's quad (-1: none) and height, mm
  int floor_mesh_id = -1;
  double floor_z_mm = 0;
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
  // Whether a pile passes every check a published scene must pass; counts a failure in `times`.
  bool Passes(const PileResult& pile, StageTimes* times) const;
  // physics.drop_mode CUT_AND_PASTE: the parts placed at random, no physics, a pure function
  // of pile_seed
  PileResult PastedPile(const std::vector<int>& object_types, uint64_t pile_seed) const;

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
    camera.width = intrinsics.width;
    camera.height = intrinsics.height;
    camera.fx = intrinsics.fx;
    camera.fy = intrinsics.fy;
    camera.cx = intrinsics.cx;
    camera.cy = intrinsics.cy;
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

SceneGenerator::SceneGenerator(const LoadedConfig& config, int32_t generator_id, uint64_t base_seed,
                               const std::string& cache_dir)
    : impl_(std::make_unique<Impl>()) {
  impl_->loaded = config;
  impl_->generator_id = generator_id;
  impl_->base_seed = base_seed;
  const config::BinConfig& bin = config.config.bin();

  // each part type: its mesh and, when the config names them, its convex collision pieces.
  std::vector<PartType> types;
  for (const config::PartConfig& part : config.config.part()) {
    PartType type;
    type.name = "part mesh '" + config.Resolve(part.mesh()) + "'";
    type.mesh = LoadMesh(config.Resolve(part.mesh()), part.scale_to_mm());
    CheckClosedSolid("'" + config.Resolve(part.mesh()) + "'", type.mesh);
    if (!part.collision_mesh().empty()) {
      type.collision_pieces =
          LoadMeshPieces(config.Resolve(part.collision_mesh()), part.scale_to_mm());
    }
    type.physics.density_kg_m3 = part.density_kg_m3();
    type.physics.friction = part.friction();
    type.physics.restitution = part.restitution();
    type.physics.rolling_friction_mm = part.rolling_friction_mm();
    types.push_back(std::move(type));
  }

  // refuse a bin too small for the parts: each must fit lying down, all of them in its volume.
  const double floor_short = std::min(bin.inner_length_mm(), bin.inner_width_mm());
  const double floor_long = std::max(bin.inner_length_mm(), bin.inner_width_mm());
  const double bin_volume = bin.inner_length_mm() * bin.inner_width_mm() * bin.inner_height_mm();
  double parts_volume = 0;
  std::ostringstream parts_text;
  std::vector<std::string> size_texts;  // for the description below
  for (size_t t = 0; t < types.size(); ++t) {
    const config::PartConfig& part = config.config.part(static_cast<int>(t));
    const Eigen::Vector3d sizes = Bounds(types[t].mesh).sizes();
    std::vector<double> extent = {sizes.x(), sizes.y(), sizes.z()};
    std::sort(extent.begin(), extent.end());
    const Eigen::Vector3d sides(extent[0], extent[1], extent[2]);
    const double pixels =
        config.config.camera().fx() * extent[2] / config.config.camera().height_mm();
    size_texts.push_back(PartSizeText(sides, pixels, config.config.camera().height_mm()));
    if (pixels < kMinPartPixels || extent[2] * kMinPartFractionOfBin < floor_short) {
      std::ostringstream text;
      text << config.path << ": part[" << t << "] (" << config.Resolve(part.mesh()) << ") is "
           << SizeText(sides) << ", " << PixelsText(pixels) << " px across at the camera's "
           << config.config.camera().height_mm() << " mm: too small to label (at least "
           << kMinPartPixels << " px and 1/" << kMinPartFractionOfBin << " of the bin floor's "
           << floor_short << " mm); "
           << ScaleHint(extent[2], part.scale_to_mm(), floor_short, floor_long);
      throw ConfigError(text.str());
    }
    if (extent[1] > floor_short || extent[2] > floor_long) {
      std::ostringstream text;
      text << config.path << ": bin.inner_length_mm/inner_width_mm: part[" << t << "] ("
           << SizeText(sides) << ") does not fit on the bin floor (" << bin.inner_length_mm()
           << " x " << bin.inner_width_mm() << " mm)";
      throw ConfigError(text.str());
    }
    const int most = part.count_max() > 0 ? part.count_max() : part.count();
    parts_volume += most * sides.prod();
    parts_text << (t > 0 ? " + " : "") << most << " of " << SizeText(sides);
  }
  if (parts_volume > bin_volume) {
    std::ostringstream text;
    text << config.path << ": bin: " << parts_text.str() << " fill " << parts_volume / 1e6
         << " L of bounding boxes, more than the bin's " << bin_volume / 1e6
         << " L; enlarge the bin or lower the part counts";
    throw ConfigError(text.str());
  }

  // the bin: a tote mesh from the config, or a box bin from its sizes.
  BinSpec bin_spec{bin.inner_length_mm(),   bin.inner_width_mm(), bin.inner_height_mm(),
                   bin.wall_thickness_mm(), bin.friction(),       bin.restitution(),
                   TriangleMesh{}};
  if (!bin.mesh().empty()) {
    bin_spec.mesh = LoadMesh(config.Resolve(bin.mesh()), bin.mesh_scale_to_mm());
    const Eigen::AlignedBox3d box = Bounds(bin_spec.mesh);
    const double half_l = bin.inner_length_mm() / 2, half_w = bin.inner_width_mm() / 2;
    if (box.min().x() > -half_l || box.max().x() < half_l || box.min().y() > -half_w ||
        box.max().y() < half_w || box.min().z() > 0 || box.max().z() < bin.inner_height_mm()) {
      std::ostringstream text;
      text << config.Resolve(bin.mesh()) << ": bin.mesh spans x " << box.min().x() << ".."
           << box.max().x() << ", y " << box.min().y() << ".." << box.max().y() << ", z "
           << box.min().z() << ".." << box.max().z()
           << " mm, which does not enclose the inner box (x, y within +-" << half_l << ", +-"
           << half_w << ", z 0.." << bin.inner_height_mm()
           << "); the mesh's origin must be the centre of its inner floor, z up";
      throw ConfigError(text.str());
    }
  }

  // physics.
  const config::PhysicsConfig& p = config.config.physics();
  SimulationParams params;
  params.time_step_s = p.time_step_s();
  params.max_sim_time_s = p.max_sim_time_s();
  params.settle_translation_mm = p.settle_translation_mm();
  params.settle_rotation_deg = p.settle_rotation_deg();
  params.settle_window_s = p.settle_window_s();
  params.drop_height_mm = p.drop_height_mm();
  params.drop_mode = p.drop_mode() == config::PhysicsConfig::SEQUENTIAL ? DropMode::kSequential
                                                                        : DropMode::kRandomVolume;
  params.drop_point_mm = Eigen::Vector2d(p.drop_point_x_mm(), p.drop_point_y_mm());
  impl_->simulator = std::make_unique<PileSimulator>(types, bin_spec, params, cache_dir);

  // rendering, and the class ids of the labelled types.
  impl_->renderer =
      std::make_unique<Renderer>(config.config.camera().width(), config.config.camera().height());
  std::vector<std::string> class_names;
  std::ostringstream description;
  for (size_t t = 0; t < types.size(); ++t) {
    const config::PartConfig& part = config.config.part(static_cast<int>(t));
    TypeInScene type;
    type.mesh_id = impl_->renderer->AddMesh(types[t].mesh);
    type.material.color =
        Eigen::Vector3d(part.color_r(), part.color_g(), part.color_b()).cast<float>();
    type.material.specular = static_cast<float>(part.specular());
    type.material.shininess = static_cast<float>(part.shininess());
    type.material.metallic = static_cast<float>(part.metallic());
    type.material.roughness = part.has_roughness() ? static_cast<float>(part.roughness()) : -1.f;
    type.use_file_materials = part.use_file_materials();
    type.detail = DetailOf(part.detail(), part.detail_strength(), part.detail_scale_mm());
    if (part.role() != config::PartConfig::DISTRACTOR) {
      auto it = std::find(class_names.begin(), class_names.end(), part.class_name());
      if (it == class_names.end()) it = class_names.insert(it, part.class_name());
      type.class_id = static_cast<int>(it - class_names.begin()) + 1;
      if (type.class_id > static_cast<int>(impl_->models.size())) {
        impl_->models.push_back(ModelOf(types[t].mesh, type.class_id, part));
      }
    }
    impl_->types.push_back(type);
    const TriangleMesh& mesh = types[t].mesh;
    int textured = 0;
    for (const MeshMaterial& material : mesh.materials)
      textured += material.texture.empty() ? 0 : 1;
    description << (part.role() == config::PartConfig::PART ? "part " : "distractor ")
                << config.Resolve(part.mesh()) << ": " << mesh.triangles.size() << " triangles, "
                << (mesh.materials.empty() || !part.use_file_materials()
                        ? std::string("configured material")
                        : std::to_string(mesh.materials.size()) + " file material(s), " +
                              std::to_string(textured) + " textured")
                << ", " << impl_->simulator->CollisionDescription(static_cast<int>(t)) << ", "
                << size_texts[t] << "\n";
  }
  // a box bin collides as boxes (exact, fast) and is drawn from the same sizes
  impl_->bin_mesh_id = impl_->renderer->AddMesh(
      bin.mesh().empty() ? MakeOpenBinMesh(bin.inner_length_mm(), bin.inner_width_mm(),
                                           bin.inner_height_mm(), bin.wall_thickness_mm())
                         : bin_spec.mesh);
  impl_->bin_material.color =
      Eigen::Vector3d(bin.color_r(), bin.color_g(), bin.color_b()).cast<float>();
  impl_->bin_material.specular = static_cast<float>(bin.specular());
  impl_->bin_material.shininess = static_cast<float>(bin.shininess());
  impl_->bin_material.metallic = static_cast<float>(bin.metallic());
  impl_->bin_material.roughness = bin.has_roughness() ? static_cast<float>(bin.roughness()) : -1.f;
  impl_->bin_detail = DetailOf(bin.detail(), bin.detail_strength(), bin.detail_scale_mm());
  // a table under the bin: a square 2 m wide, 0.5 mm below the bin's lowest point (it hides the
  // background wherever the camera looks)
  if (config.config.surroundings().table_probability() > 0) {
    const double bottom =
        bin.mesh().empty() ? -bin.wall_thickness_mm() : Bounds(bin_spec.mesh).min().z();
    impl_->floor_z_mm = bottom - 0.5;
    impl_->floor_mesh_id = impl_->renderer->AddMesh(MakeSquareMesh(2000));
  }

  // physically based shading: the procedural halls and the user's environment files, each
  // prefiltered once here
  const config::RenderingConfig& rendering = config.config.rendering();
  if (rendering.shading() == config::RenderingConfig::PBR) {
    const int max_samples = impl_->renderer->MaxMsaaSamples();
    if (rendering.msaa_samples() > max_samples) {
      throw ConfigError(config.path +
                        ": rendering.msaa_samples: " + std::to_string(rendering.msaa_samples()) +
                        " is more than the " + std::to_string(max_samples) +
                        " this renderer takes (" + impl_->renderer->Description() + ")");
    }
    const Clock::time_point start = Clock::now();
    for (int k = 0; k < rendering.procedural_halls(); ++k) {
      impl_->environment_ids.push_back(
          impl_->renderer->AddEnvironment(Prefilter(MakeHallEnvironment(k, 128))));
    }
    std::vector<std::string> files;
    if (!rendering.environment_dir().empty()) {
      try {
        files = ListEnvironmentFiles(config.Resolve(rendering.environment_dir()));
        for (const std::string& file : files) {
          impl_->environment_ids.push_back(
              impl_->renderer->AddEnvironment(Prefilter(LoadEnvironment(file))));
        }
      } catch (const std::runtime_error& error) {
        throw ConfigError(config.path + ": rendering.environment_dir: " + error.what());
      }
    }
    description << "shading: physically based, " << rendering.msaa_samples()
                << " samples per pixel; environments: " << rendering.procedural_halls()
                << " procedural halls";
    if (!files.empty()) {
      description << ", " << files.size() << " files in "
                  << config.Resolve(rendering.environment_dir());
    }
    description << " (prepared in " << static_cast<int>(MillisecondsSince(start)) << " ms)\n";
  } else {
    description << "shading: Blinn-Phong (the paper's), no anti-aliasing\n";
  }

  // camera ranges that would lose the bin too often are refused now, not mid-run
  try {
    CheckCameraPoseRanges(config.config.camera(), impl_->CameraIntrinsics(), bin);
  } catch (const std::runtime_error& error) {
    throw ConfigError(config.path + ": " + error.what());
  }

  // backgrounds: the image folder is listed once, here
  const config::BackgroundConfig& background = config.config.background();
  try {
    impl_->backgrounds = std::make_unique<BackgroundSource>(
        background, background.image_dir().empty() ? "" : config.Resolve(background.image_dir()));
  } catch (const std::runtime_error& error) {
    throw ConfigError(config.path + ": " + error.what());
  }
  if (!background.image_dir().empty()) {
    description << "backgrounds: " << impl_->backgrounds->image_paths().size() << " images in "
                << config.Resolve(background.image_dir()) << "\n";
  }
  description << "renderer: " << impl_->renderer->Description();
  impl_->description = description.str();
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
}

int SceneGenerator::views_per_pile() const { return impl_->config().physics().views_per_pile(); }

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
    pile = simulator->Simulate(object_types, pile_seed);
    // every check a published scene must pass
    if (Passes(pile, &local)) break;
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
  const std::vector<int> order =
      simulator->PickOrder(state->object_types, state->world_from_object);
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
};

scene SceneGenerator::Finish(const SettledPile& settled, int64_t seq, StageTimes* times) {
  return Encode(Render(settled, seq, times), times);
}

RenderedScene SceneGenerator::Render(const SettledPile& settled, int64_t seq, StageTimes* times) {
  const config::GeneratorConfig& config = impl_->config();
  const int views = views_per_pile();
  if (seq < settled.first_seq || seq >= settled.first_seq + views) {
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
  const std::vector<int>& object_types = settled.object_types;
  Clock::time_point start;

  // the scene's look, each lever from its own engine: camera, lights, backgrounds, materials.
  std::mt19937_64 camera_engine = LeverEngine(seed, Lever::kCamera);
  std::mt19937_64 lighting_engine = LeverEngine(seed, Lever::kLighting);
  std::mt19937_64 appearance_engine = LeverEngine(seed, Lever::kAppearance);
  std::mt19937_64 background_engine = LeverEngine(seed, Lever::kBackground);
  std::mt19937_64 sensor_engine = LeverEngine(seed, Lever::kSensor);
  std::mt19937_64 environment_engine = LeverEngine(seed, Lever::kEnvironment);
  start = Clock::now();
  const CameraModel camera = impl_->Camera(camera_engine);
  const std::vector<Light> lights = SampleLights(config.lighting(), lighting_engine);
  RenderOptions options;
  options.background_image =
      impl_->backgrounds->Draw(camera.width, camera.height, background_engine);
  options.shadows = config.lighting().shadows();
  options.shadow_map_size = config.lighting().shadow_map_size();
  // physically based: an environment, its turn and strength (three draws whatever the settings)
  const config::RenderingConfig& rendering = config.rendering();
  const double environment_draw = Uniform(environment_engine, 0, 1);
  const double yaw_deg = Uniform(environment_engine, 0, 360);
  const double log_intensity =
      Uniform(environment_engine, std::log(std::max(rendering.environment_intensity_min(), 1e-9)),
              std::log(std::max(rendering.environment_intensity_max(), 1e-9)));
  if (rendering.shading() == config::RenderingConfig::PBR) {
    options.shading = Shading::kPbr;
    options.msaa_samples = rendering.msaa_samples();
    const size_t count = impl_->environment_ids.size();
    options.environment_id = impl_->environment_ids[std::min(
        count - 1, static_cast<size_t>(environment_draw * static_cast<double>(count)))];
    options.environment_yaw_deg = rendering.environment_random_yaw() ? yaw_deg : 0;
    options.environment_intensity = rendering.environment_intensity_max() > 0
                                        ? static_cast<float>(std::exp(log_intensity))
                                        : 0.f;
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
  if (config.bin().visible()) {
    DrawItem bin_item;
    bin_item.mesh_id = impl_->bin_mesh_id;
    bin_item.instance_id = 0;
    bin_item.material = impl_->bin_material;
    bin_item.detail = impl_->bin_detail;
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
    items.push_back(bin_item);
  }
  if (pbr && around.floor != DrawnSurroundings::Floor::kNone && impl_->floor_mesh_id >= 0) {
    DrawItem floor;
    floor.mesh_id = impl_->floor_mesh_id;
    floor.instance_id = 0;
    floor.world_from_object = Eigen::Translation3d(0, 0, impl_->floor_z_mm);
    floor.material.color = around.floor_color;
    floor.material.metallic = 0;
    floor.material.roughness = around.floor_roughness;
    floor.material.specular = 0.5f;
    // a table is scuffed over centimetres; a belt has fine grooves along the bin's length (x)
    const bool conveyor = around.floor == DrawnSurroundings::Floor::kConveyor;
    floor.detail.kind = conveyor ? SurfaceDetail::Kind::kBrushed : SurfaceDetail::Kind::kScuffed;
    floor.detail.strength = around.floor_detail_strength;
    floor.detail.scale_mm = conveyor ? 3.f : 20.f;
    floor.detail = PlacedDetail(floor.detail, seed, 1);
    floor.casts_shadow = false;
    items.push_back(floor);
  }
  // labelled objects get instance ids 1, 2, ...; unlabelled distractors draw as 0, like the bin
  std::vector<ObjectTruth> objects;
  for (size_t i = 0; i < settled.world_from_object.size(); ++i) {
    const int t = object_types[i];
    const config::PartConfig& part = config.part(t);
    const TypeInScene& type = impl_->types[t];
    DrawItem part_item;
    part_item.mesh_id = type.mesh_id;
    part_item.world_from_object = settled.world_from_object[i];
    part_item.material = type.material;
    part_item.use_mesh_materials = type.use_file_materials;
    part_item.gain = gains[t];
    part_item.detail = PlacedDetail(type.detail, seed, 2 + i);
    if (type.class_id > 0) {
      ObjectTruth object;
      object.instance_id = static_cast<int>(objects.size() + 1);
      object.class_id = type.class_id;
      object.class_name = part.class_name();
      object.world_from_object = settled.world_from_object[i];
      object.resting_face =
          RestingFace(impl_->simulator->hull_faces(t), settled.world_from_object[i].linear());
      objects.push_back(object);
      part_item.instance_id = static_cast<uint16_t>(object.instance_id);
    }
    items.push_back(part_item);
  }
  RenderResult rendered = impl_->renderer->Render(camera, lights, options, items);
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
  out.camera.width = camera.width;
  out.camera.height = camera.height;
  out.camera.fx = camera.fx;
  out.camera.fy = camera.fy;
  out.camera.cx = camera.cx;
  out.camera.cy = camera.cy;
  out.camera.world_from_camera = ToPoseMessage(camera.world_from_camera);
  out.camera.depth_scale_mm = config.camera().depth_scale_mm();
  out.instances =
      LabelInstances(rendered.instance, silhouettes, beyond, objects, camera.world_from_camera,
                     config.annotation().min_visib_fract(),
                     config.annotation().occlusion_rule() == config::AnnotationConfig::IGNORE,
                     config.annotation().min_visible_px());
  out.num_instances = static_cast<int32_t>(out.instances.size());
  local.annotate_ms = MillisecondsSince(start);

  // what the encoding stage needs: the images and this scene's sensor draw
  auto images = std::make_shared<RenderedImages>();
  images->color = rendered.color;
  images->color_linear = rendered.color_linear;
  images->depth_mm = rendered.depth_mm;
  images->instance = rendered.instance;
  images->sensor = SampleSensorEffects(config.sensor(), sensor_engine);
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
