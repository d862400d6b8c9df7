#include "gen/scene/scene_generator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>
#include <sstream>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "gen/annotate/labels.h"
#include "gen/annotate/pose.h"
#include "gen/mesh/mesh.h"
#include "gen/physics/pile.h"
#include "gen/render/renderer.h"

namespace stackgen {
namespace {

using Clock = std::chrono::steady_clock;

double MillisecondsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

uint64_t SplitMix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// largest penetration a published scene may have, mm.
constexpr double kMaxPenetrationMm = 0.5;

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
  uint64_t seed = SplitMix64(base_seed);
  seed = SplitMix64(seed ^ static_cast<uint64_t>(static_cast<uint32_t>(generator_id)));
  seed = SplitMix64(seed ^ static_cast<uint64_t>(seq));
  return SplitMix64(seed ^ static_cast<uint64_t>(redraw));
}

struct SceneGenerator::Impl {
  LoadedConfig loaded;
  int32_t generator_id = 0;
  uint64_t base_seed = 0;
  std::unique_ptr<PileSimulator> simulator;
  std::unique_ptr<Renderer> renderer;
  int part_mesh_id = 0;
  int bin_mesh_id = 0;
  std::string description;

  const config::GeneratorConfig& config() const { return loaded.config; }

  // the pinhole camera of the config.
  CameraModel Camera() const {
    const config::CameraConfig& c = config().camera();
    CameraModel camera;
    camera.width = c.width();
    camera.height = c.height();
    camera.fx = c.fx();
    camera.fy = c.fy();
    const Eigen::Vector2d principal = PrincipalPoint(c);
    camera.cx = principal.x();
    camera.cy = principal.y();
    camera.world_from_camera = WorldFromCamera(c);
    return camera;
  }
};

SceneGenerator::SceneGenerator(const LoadedConfig& config, int32_t generator_id,
                               uint64_t base_seed, const std::string& cache_dir)
    : impl_(std::make_unique<Impl>()) {
  impl_->loaded = config;
  impl_->generator_id = generator_id;
  impl_->base_seed = base_seed;
  const config::PartConfig& part = config.config.part();
  const config::BinConfig& bin = config.config.bin();

  // the part, and its convex collision pieces when the config names them.
  const TriangleMesh part_mesh = LoadMesh(config.Resolve(part.mesh()), part.scale_to_mm());
  std::vector<TriangleMesh> pieces;
  if (!part.collision_mesh().empty()) {
    pieces = LoadMeshPieces(config.Resolve(part.collision_mesh()), part.scale_to_mm());
  }

  // refuse a bin too small for the parts: each must fit lying down, all of them in its volume.
  const Eigen::Vector3d sizes = Bounds(part_mesh).sizes();
  std::vector<double> extent = {sizes.x(), sizes.y(), sizes.z()};
  std::sort(extent.begin(), extent.end());
  const double floor_short = std::min(bin.inner_length_mm(), bin.inner_width_mm());
  const double floor_long = std::max(bin.inner_length_mm(), bin.inner_width_mm());
  const double parts_volume = part.count() * extent[0] * extent[1] * extent[2];
  const double bin_volume = bin.inner_length_mm() * bin.inner_width_mm() * bin.inner_height_mm();
  std::ostringstream size;
  size << extent[2] << " x " << extent[1] << " x " << extent[0] << " mm";
  if (extent[1] > floor_short || extent[2] > floor_long) {
    throw ConfigError(config.path + ": bin.inner_length_mm/inner_width_mm: the part (" +
                      size.str() + ") does not fit on the bin floor (" +
                      std::to_string(bin.inner_length_mm()) + " x " +
                      std::to_string(bin.inner_width_mm()) + " mm)");
  }
  if (parts_volume > bin_volume) {
    std::ostringstream text;
    text << config.path << ": bin: " << part.count() << " parts of " << size.str()
         << " fill " << parts_volume / 1e6 << " L of bounding boxes, more than the bin's "
         << bin_volume / 1e6 << " L; enlarge the bin or lower part.count";
    throw ConfigError(text.str());
  }

  // physics.
  const config::PhysicsConfig& p = config.config.physics();
  PartPhysics physics;
  physics.density_kg_m3 = part.density_kg_m3();
  physics.friction = part.friction();
  physics.restitution = part.restitution();
  SimulationParams params;
  params.time_step_s = p.time_step_s();
  params.max_sim_time_s = p.max_sim_time_s();
  params.settle_translation_mm = p.settle_translation_mm();
  params.settle_rotation_deg = p.settle_rotation_deg();
  params.settle_window_s = p.settle_window_s();
  params.drop_height_mm = p.drop_height_mm();
  const BinSpec bin_spec{bin.inner_length_mm(), bin.inner_width_mm(), bin.inner_height_mm(),
                         bin.wall_thickness_mm()};
  impl_->simulator =
      std::make_unique<PileSimulator>(part_mesh, pieces, physics, bin_spec, params, cache_dir);

  // rendering.
  impl_->renderer =
      std::make_unique<Renderer>(config.config.camera().width(), config.config.camera().height());
  impl_->part_mesh_id = impl_->renderer->AddMesh(part_mesh);
  impl_->bin_mesh_id = impl_->renderer->AddMesh(
      MakeOpenBinMesh(bin.inner_length_mm(), bin.inner_width_mm(), bin.inner_height_mm(),
                      bin.wall_thickness_mm()));
  impl_->description = "part " + config.Resolve(part.mesh()) + ": " +
                       std::to_string(part_mesh.triangles.size()) + " triangles, " +
                       impl_->simulator->CollisionDescription() + "\nrenderer: " +
                       impl_->renderer->Description();
}

SceneGenerator::~SceneGenerator() = default;

std::string SceneGenerator::Description() const { return impl_->description; }

scene SceneGenerator::Generate(int64_t seq, StageTimes* times) {
  const config::GeneratorConfig& config = impl_->config();
  StageTimes local;

  // drop the parts; a drop that fails a check is redrawn with a derived seed.
  Clock::time_point start = Clock::now();
  uint64_t seed = 0;
  PileResult pile;
  for (int redraw = 0;; ++redraw) {
    if (redraw > config.physics().max_redraws()) {
      throw std::runtime_error("scene " + std::to_string(seq) + ": " +
                               std::to_string(redraw) +
                               " drops in a row failed to settle inside the bin; check the "
                               "physics and bin settings");
    }
    seed = SceneSeed(impl_->base_seed, impl_->generator_id, seq, redraw);
    std::mt19937_64 physics_rng(seed);
    pile = impl_->simulator->Simulate(config.part().count(), physics_rng());
    if (pile.settled && pile.num_outside == 0 && pile.max_penetration_mm <= kMaxPenetrationMm) {
      break;
    }
    ++local.redraws;
  }
  local.physics_ms = MillisecondsSince(start);

  // appearance drawn from the scene's own engine, after the physics seed.
  std::mt19937_64 rng(SplitMix64(seed));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto uniform = [&](double min, double max) { return min + (max - min) * unit(rng); };
  const config::LightingConfig& lighting = config.lighting();
  Light light;
  const double tilt = uniform(0, lighting.max_tilt_deg()) * M_PI / 180;
  const double azimuth = uniform(0, 2 * M_PI);
  light.direction_world = Eigen::Vector3f(static_cast<float>(std::sin(tilt) * std::cos(azimuth)),
                                          static_cast<float>(std::sin(tilt) * std::sin(azimuth)),
                                          static_cast<float>(-std::cos(tilt)));
  light.ambient = static_cast<float>(uniform(lighting.ambient_min(), lighting.ambient_max()));
  light.diffuse = static_cast<float>(uniform(lighting.diffuse_min(), lighting.diffuse_max()));
  light.specular = static_cast<float>(uniform(lighting.specular_min(), lighting.specular_max()));
  Eigen::Vector3f background;
  for (int i = 0; i < 3; ++i) {
    background[i] = static_cast<float>(uniform(config.background().min(), config.background().max()));
  }

  // render the bin and the parts (instance ids 1..N), then each part alone.
  start = Clock::now();
  const CameraModel camera = impl_->Camera();
  std::vector<DrawItem> items;
  DrawItem bin_item;
  bin_item.mesh_id = impl_->bin_mesh_id;
  bin_item.instance_id = 0;
  bin_item.material.color = Eigen::Vector3f(static_cast<float>(config.bin().color_r()),
                                            static_cast<float>(config.bin().color_g()),
                                            static_cast<float>(config.bin().color_b()));
  bin_item.material.specular = 0.15f;
  bin_item.material.shininess = 8;
  items.push_back(bin_item);
  std::vector<ObjectTruth> objects;
  for (size_t i = 0; i < pile.world_from_object.size(); ++i) {
    DrawItem part_item;
    part_item.mesh_id = impl_->part_mesh_id;
    part_item.world_from_object = pile.world_from_object[i];
    part_item.instance_id = static_cast<uint16_t>(i + 1);
    part_item.material.color = Eigen::Vector3f(static_cast<float>(config.part().color_r()),
                                               static_cast<float>(config.part().color_g()),
                                               static_cast<float>(config.part().color_b()));
    part_item.material.specular = 0.6f;
    part_item.material.shininess = 40;
    items.push_back(part_item);
    objects.push_back(ObjectTruth{static_cast<int>(i + 1), 1, config.part().class_name(),
                                  pile.world_from_object[i]});
  }
  const RenderResult rendered = impl_->renderer->Render(camera, {light}, background, items);
  const std::vector<cv::Mat> silhouettes = impl_->renderer->RenderSilhouettes(camera, items);
  local.render_ms = MillisecondsSince(start);

  // label every object from the same render.
  start = Clock::now();
  scene out;
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
  out.instances = LabelInstances(rendered.instance, silhouettes, objects, camera.world_from_camera,
                                 config.annotation().min_visib_fract());
  out.num_instances = static_cast<int32_t>(out.instances.size());
  local.annotate_ms = MillisecondsSince(start);

  // encode the images: colour or gray, depth in depth_scale units, instance ids.
  start = Clock::now();
  const config::OutputConfig::Encoding encoding = config.output().image_encoding();
  if (config.camera().grayscale()) {
    cv::Mat gray;
    cv::cvtColor(rendered.color, gray, cv::COLOR_RGB2GRAY);
    out.color = EncodeImage(gray, image::PIXEL_GRAY8, encoding);
  } else {
    out.color = EncodeImage(rendered.color, image::PIXEL_RGB8, encoding);
  }
  cv::Mat depth;
  rendered.depth_mm.convertTo(depth, CV_16U, 1.0 / config.camera().depth_scale_mm());
  out.depth = EncodeImage(depth, image::PIXEL_DEPTH16, encoding);
  out.instance_map = EncodeImage(rendered.instance, image::PIXEL_INSTANCE16, encoding);
  local.encode_ms = MillisecondsSince(start);

  if (times != nullptr) {
    times->physics_ms += local.physics_ms;
    times->render_ms += local.render_ms;
    times->annotate_ms += local.annotate_ms;
    times->encode_ms += local.encode_ms;
    times->redraws += local.redraws;
  }
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

}  // namespace stackgen
