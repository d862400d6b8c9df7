#include <algorithm>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

#include "gen/mesh/mesh.h"
#include "gen/mesh/symmetry.h"
#include "gen/physics/mass_properties.h"
#include "gen/render/environment.h"
#include "gen/scene/scene_generator_internal.h"

// Setting up a SceneGenerator: the config's parts, bin, camera, environments and backgrounds
// loaded and checked once, before the first scene.

namespace stackgen {

using namespace scene_internal;

namespace {

// The renderer's surface detail of a config's kind, strength and feature size.
SurfaceDetail DetailOf(config::SurfaceDetail::Kind kind, double strength, double scale_mm) {
  SurfaceDetail detail;
  detail.kind = kind == config::SurfaceDetail::CAST      ? SurfaceDetail::Kind::kCast
                : kind == config::SurfaceDetail::BRUSHED ? SurfaceDetail::Kind::kBrushed
                : kind == config::SurfaceDetail::SCUFFED ? SurfaceDetail::Kind::kScuffed
                : kind == config::SurfaceDetail::MOULDED ? SurfaceDetail::Kind::kMoulded
                : kind == config::SurfaceDetail::WOOD    ? SurfaceDetail::Kind::kWood
                                                         : SurfaceDetail::Kind::kNone;
  detail.strength = static_cast<float>(strength);
  detail.scale_mm = static_cast<float>(scale_mm);
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

// "60 x 40 x 10 mm": the sides of a box, longest first.
std::string SizeText(const Eigen::Vector3d& sides) {
  std::ostringstream text;
  text << sides[2] << " x " << sides[1] << " x " << sides[0] << " mm";
  return text.str();
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

// Each part type: its mesh and, when the config names them, its convex collision pieces.
std::vector<PartType> LoadPartTypes(const LoadedConfig& config) {
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

  return types;
}

// Refuses a bin too small for the parts: each must fit lying down, all of them in its volume.
// Returns each type's size text for the description.
std::vector<std::string> CheckPartSizes(const LoadedConfig& config,
                                        const std::vector<PartType>& types) {
  const config::BinConfig& bin = config.config.bin();
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

  return size_texts;
}

// The bin: a tote mesh from the config, or a box bin from its sizes.
BinSpec LoadBinSpec(const LoadedConfig& config) {
  const config::BinConfig& bin = config.config.bin();
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

  return bin_spec;
}

SimulationParams SimulationParamsOf(const config::PhysicsConfig& p) {
  SimulationParams params;
  params.time_step_s = p.time_step_s();
  params.rest_time_step_s = p.rest_time_step_s();
  params.max_sim_time_s = p.max_sim_time_s();
  params.settle_translation_mm = p.settle_translation_mm();
  params.settle_rotation_deg = p.settle_rotation_deg();
  params.settle_window_s = p.settle_window_s();
  params.drop_height_mm = p.drop_height_mm();
  params.drop_mode = p.drop_mode() == config::PhysicsConfig::SEQUENTIAL ? DropMode::kSequential
                                                                        : DropMode::kRandomVolume;
  params.drop_point_mm = Eigen::Vector2d(p.drop_point_x_mm(), p.drop_point_y_mm());
  params.solver_iterations = p.solver_iterations();
  params.free_friction_while_falling = p.free_friction_while_falling();

  return params;
}

}  // namespace

void SceneGenerator::Impl::AddPartTypes(const std::vector<PartType>& part_types,
                                        const std::vector<std::string>& size_texts,
                                        std::ostringstream* description) {
  // the class ids of the labelled types: 1, 2, ... by first class_name
  std::vector<std::string> class_names;
  for (size_t t = 0; t < part_types.size(); ++t) {
    const config::PartConfig& part = config().part(static_cast<int>(t));
    TypeInScene type;
    type.mesh_id = renderer->AddMesh(part_types[t].mesh);
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
      if (type.class_id > static_cast<int>(models.size())) {
        models.push_back(ModelOf(part_types[t].mesh, type.class_id, part));
      }
    }
    types.push_back(type);
    const TriangleMesh& mesh = part_types[t].mesh;
    int textured = 0;
    for (const MeshMaterial& material : mesh.materials)
      textured += material.texture.empty() ? 0 : 1;
    *description << (part.role() == config::PartConfig::PART ? "part " : "distractor ")
                 << loaded.Resolve(part.mesh()) << ": ";
    if (part.role() != config::PartConfig::DISTRACTOR) {
      const bool from_file = t < loaded.class_from_file.size() && loaded.class_from_file[t];
      *description << "class " << type.class_id << " \"" << part.class_name() << "\""
                   << (from_file ? " (the file's name; set class_name to change it)" : "") << ", ";
    }
    *description << mesh.triangles.size() << " triangles, "
                 << (mesh.materials.empty() || !part.use_file_materials()
                         ? std::string("configured material")
                         : std::to_string(mesh.materials.size()) + " file material(s), " +
                               std::to_string(textured) + " textured")
                 << ", " << simulator->CollisionDescription(static_cast<int>(t)) << ", "
                 << size_texts[t] << "\n";
  }
}

void SceneGenerator::Impl::AddBinAndTable(const BinSpec& bin_spec) {
  const config::BinConfig& bin = config().bin();
  // a box bin collides as boxes (exact, fast) and is drawn from the same sizes
  bin_mesh_id = renderer->AddMesh(
      bin.mesh().empty() ? MakeOpenBinMesh(bin.inner_length_mm(), bin.inner_width_mm(),
                                           bin.inner_height_mm(), bin.wall_thickness_mm())
                         : bin_spec.mesh);
  bin_material.color = Eigen::Vector3d(bin.color_r(), bin.color_g(), bin.color_b()).cast<float>();
  bin_material.specular = static_cast<float>(bin.specular());
  bin_material.shininess = static_cast<float>(bin.shininess());
  bin_material.metallic = static_cast<float>(bin.metallic());
  bin_material.roughness = bin.has_roughness() ? static_cast<float>(bin.roughness()) : -1.f;
  bin_detail = DetailOf(bin.detail(), bin.detail_strength(), bin.detail_scale_mm());
  // a table under the bin: a square 2 m wide, 0.5 mm below the bin's lowest point (it hides the
  // background wherever the camera looks)
  if (config().surroundings().table_probability() > 0) {
    const double bottom =
        bin.mesh().empty() ? -bin.wall_thickness_mm() : Bounds(bin_spec.mesh).min().z();
    floor_z_mm = bottom - 0.5;
    floor_mesh_id = renderer->AddMesh(MakeSquareMesh(2000));
  }
}

void SceneGenerator::Impl::AddGraspMeshes(const std::vector<PartType>& part_types,
                                          const BinSpec& bin_spec) {
  const config::BinConfig& bin = config().bin();
  grasp_scene = std::make_unique<GraspScene>();
  for (size_t t = 0; t < part_types.size(); ++t) {
    part_meshes.push_back(part_types[t].mesh);
    types[t].grasp_mesh_id = grasp_scene->AddMesh(part_types[t].mesh);
    types[t].center_of_mass_mm =
        ComputeMassProperties(part_types[t].mesh, part_types[t].physics.density_kg_m3,
                              "part " + std::to_string(t))
            .center_of_mass_mm;
  }
  bin_mesh = bin.mesh().empty() ? MakeOpenBinMesh(bin.inner_length_mm(), bin.inner_width_mm(),
                                                  bin.inner_height_mm(), bin.wall_thickness_mm())
                                : bin_spec.mesh;
  grasp_bin_mesh_id = grasp_scene->AddMesh(bin_mesh);
}

void SceneGenerator::Impl::AddEnvironments(std::ostringstream* description) {
  // physically based shading: the procedural halls and the user's environment files, each
  // prefiltered once here
  const config::RenderingConfig& rendering = config().rendering();
  if (rendering.shading() == config::RenderingConfig::PBR) {
    const int max_samples = renderer->MaxMsaaSamples();
    if (rendering.msaa_samples() > max_samples) {
      throw ConfigError(loaded.path +
                        ": rendering.msaa_samples: " + std::to_string(rendering.msaa_samples()) +
                        " is more than the " + std::to_string(max_samples) +
                        " this renderer takes (" + renderer->Description() + ")");
    }
    const Clock::time_point start = Clock::now();
    for (int k = 0; k < rendering.procedural_halls(); ++k) {
      environment_ids.push_back(renderer->AddEnvironment(Prefilter(MakeHallEnvironment(k, 128))));
    }
    std::vector<std::string> files;
    if (!rendering.environment_dir().empty()) {
      try {
        files = ListEnvironmentFiles(loaded.Resolve(rendering.environment_dir()));
        for (const std::string& file : files) {
          environment_ids.push_back(renderer->AddEnvironment(Prefilter(LoadEnvironment(file))));
        }
      } catch (const std::runtime_error& error) {
        throw ConfigError(loaded.path + ": rendering.environment_dir: " + error.what());
      }
    }
    *description << "shading: physically based, " << rendering.msaa_samples()
                 << " samples per pixel; environments: " << rendering.procedural_halls()
                 << " procedural halls";
    if (!files.empty()) {
      *description << ", " << files.size() << " files in "
                   << loaded.Resolve(rendering.environment_dir());
    }
    *description << " (prepared in " << static_cast<int>(MillisecondsSince(start)) << " ms)\n";
  } else {
    *description << "shading: Blinn-Phong (the paper's), no anti-aliasing\n";
  }
}

SceneGenerator::SceneGenerator(const LoadedConfig& config, int32_t generator_id, uint64_t base_seed,
                               const std::string& cache_dir)
    : impl_(std::make_unique<Impl>()) {
  impl_->loaded = config;
  impl_->generator_id = generator_id;
  impl_->base_seed = base_seed;
  const config::BinConfig& bin = config.config.bin();
  const std::vector<PartType> types = LoadPartTypes(config);
  const std::vector<std::string> size_texts = CheckPartSizes(config, types);
  const BinSpec bin_spec = LoadBinSpec(config);
  impl_->simulator = std::make_unique<PileSimulator>(
      types, bin_spec, SimulationParamsOf(config.config.physics()), cache_dir);
  impl_->renderer =
      std::make_unique<Renderer>(config.config.camera().width(), config.config.camera().height());
  std::ostringstream description;
  impl_->AddPartTypes(types, size_texts, &description);
  impl_->AddBinAndTable(bin_spec);
  if (config.config.grasps().suction() || config.config.grasps().parallel_jaw()) {
    impl_->AddGraspMeshes(types, bin_spec);
  }
  const config::PhysicsConfig& physics = config.config.physics();
  if (physics.drop_mode() == config::PhysicsConfig::CUT_AND_PASTE) {
    description << "physics: none (CUT_AND_PASTE: parts placed as drawn)\n";
  } else {
    description << "physics: published at rest, every part moving less than "
                << physics.settle_translation_mm() << " mm and " << physics.settle_rotation_deg()
                << " degree over " << physics.settle_window_s()
                << " s (physics.settle_*); a drop not at rest within " << physics.max_sim_time_s()
                << " s is drawn again\n";
  }
  impl_->AddEnvironments(&description);

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

}  // namespace stackgen
