#include "gen/config/config.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

namespace stackgen {
namespace {

namespace pb = google::protobuf;

// collects the parser's errors as "file:line:column: message".
class ErrorCollector : public pb::io::ErrorCollector {
 public:
  explicit ErrorCollector(std::string name) : name_(std::move(name)) {}
  void AddError(int line, pb::io::ColumnNumber column, const std::string& message) override {
    if (first_.empty()) {
      first_ = name_ + ":" + std::to_string(line + 1) + ":" + std::to_string(column + 1) + ": " +
               message;
    }
  }
  const std::string& first() const { return first_; }

 private:
  std::string name_;
  std::string first_;
};

// names a field in an error: "file:line: part.count" when the file sets it, else the default.
class FieldNamer {
 public:
  FieldNamer(std::string name, const pb::TextFormat::ParseInfoTree* tree)
      : name_(std::move(name)), tree_(tree) {}

  // `index` picks the element of a repeated message field (part); -1 for singular ones.
  std::string Where(const std::string& message_field, const std::string& field,
                    int index = -1) const {
    const pb::Descriptor* root = config::GeneratorConfig::descriptor();
    const pb::FieldDescriptor* outer = root->FindFieldByName(message_field);
    const int outer_index = outer != nullptr && outer->is_repeated() ? index : -1;
    const bool outer_set = tree_ != nullptr && outer != nullptr &&
                           (outer_index < 0 || tree_->GetLocation(outer, outer_index).line >= 0);
    const pb::TextFormat::ParseInfoTree* nested =
        outer_set ? tree_->GetTreeForNested(outer, outer_index) : nullptr;
    const pb::FieldDescriptor* inner = outer != nullptr && !field.empty()
                                           ? outer->message_type()->FindFieldByName(field)
                                           : nullptr;
    int line = -1;
    if (nested != nullptr && inner != nullptr) {
      // a repeated scalar (background.kind) is located by its first element
      line = nested->GetLocation(inner, inner->is_repeated() ? 0 : -1).line;
    } else if (outer_set && field.empty()) {
      line = tree_->GetLocation(outer, outer_index).line;
    }
    std::string dotted = message_field;
    if (outer_index >= 0) dotted += "[" + std::to_string(outer_index) + "]";
    if (!field.empty()) dotted += "." + field;
    if (line >= 0) return name_ + ":" + std::to_string(line + 1) + ": " + dotted;
    return name_ + ": " + dotted + " (default)";
  }

 private:
  std::string name_;
  const pb::TextFormat::ParseInfoTree* tree_;
};

// a real camera's sensor: resolution and pixel pitch from the maker's data sheet.
struct CameraPreset {
  const char* name;
  int width;
  int height;
  double pixel_pitch_um;
};

constexpr CameraPreset kCameraPresets[] = {
    {"basler_scA1600-20gc", 1626, 1236, 4.4},   // Sony ICX274 1/1.8" CCD, the paper's camera
    {"basler_acA1300-60gc", 1280, 1024, 5.3},   // e2v EV76C560 1/1.8" CMOS
    {"basler_acA2440-20gc", 2448, 2048, 3.45},  // Sony IMX264 2/3" CMOS
    {"basler_acA1920-40gc", 1920, 1200, 5.86},  // Sony IMX249 1/1.2" CMOS
};

std::string Number(double value) {
  std::ostringstream text;
  text << value;
  return text.str();
}

// checks min <= value <= max (open bounds where asked) or throws naming the field.
void CheckRange(const FieldNamer& namer, const std::string& message_field, const std::string& field,
                double value, double min, double max, bool min_open = false, int index = -1) {
  const bool low = min_open ? !(value > min) : !(value >= min);
  if (low || !(value <= max) || !std::isfinite(value)) {
    throw ConfigError(namer.Where(message_field, field, index) + ": " + Number(value) +
                      " is out of range, must be in " + (min_open ? "(" : "[") + Number(min) +
                      ", " + Number(max) + "]");
  }
}

// the range the schema states for `field` ((stackgen.config.range)), or null when it has none
const config::Range* SchemaRange(const pb::FieldDescriptor* field) {
  const pb::FieldOptions& options = field->options();
  return options.HasExtension(config::range) ? &options.GetExtension(config::range) : nullptr;
}

// CheckRange with the range the schema states for message_field.field (which must have one)
void CheckSchemaRange(const FieldNamer& namer, const std::string& message_field,
                      const std::string& field, double value, int index = -1) {
  const pb::FieldDescriptor* outer =
      config::GeneratorConfig::descriptor()->FindFieldByName(message_field);
  const config::Range* range = SchemaRange(outer->message_type()->FindFieldByName(field));
  CheckRange(namer, message_field, field, value, range->min(), range->max(), range->min_open(),
             index);
}

// the value in force of numeric field `field` of `message` (element `k` of a repeated one)
double NumericValue(const pb::Message& message, const pb::FieldDescriptor* field, int k) {
  const pb::Reflection* r = message.GetReflection();
  const bool many = field->is_repeated();
  switch (field->cpp_type()) {
    case pb::FieldDescriptor::CPPTYPE_DOUBLE:
      return many ? r->GetRepeatedDouble(message, field, k) : r->GetDouble(message, field);
    case pb::FieldDescriptor::CPPTYPE_FLOAT:
      return many ? r->GetRepeatedFloat(message, field, k) : r->GetFloat(message, field);
    case pb::FieldDescriptor::CPPTYPE_INT32:
      return many ? r->GetRepeatedInt32(message, field, k) : r->GetInt32(message, field);
    case pb::FieldDescriptor::CPPTYPE_INT64:
      return static_cast<double>(many ? r->GetRepeatedInt64(message, field, k)
                                      : r->GetInt64(message, field));
    case pb::FieldDescriptor::CPPTYPE_UINT32:
      return many ? r->GetRepeatedUInt32(message, field, k) : r->GetUInt32(message, field);
    case pb::FieldDescriptor::CPPTYPE_UINT64:
      return static_cast<double>(many ? r->GetRepeatedUInt64(message, field, k)
                                      : r->GetUInt64(message, field));
    default:
      throw std::logic_error("(range) on a field that is not a number: " + field->full_name());
  }
}

// Every numeric field's range as the schema states it, on the value in force (the file's, or
// the default), in the schema's order: the one place ranges are checked. What depends on other
// fields is checked after, by the Validate* functions.
void CheckFieldRanges(const config::GeneratorConfig& c, const FieldNamer& n) {
  const pb::Reflection* reflection = c.GetReflection();
  const pb::Descriptor* root = c.GetDescriptor();
  for (int i = 0; i < root->field_count(); ++i) {
    const pb::FieldDescriptor* outer = root->field(i);
    if (outer->cpp_type() != pb::FieldDescriptor::CPPTYPE_MESSAGE) continue;
    const int messages = outer->is_repeated() ? reflection->FieldSize(c, outer) : 1;
    for (int m = 0; m < messages; ++m) {
      const pb::Message& message = outer->is_repeated()
                                       ? reflection->GetRepeatedMessage(c, outer, m)
                                       : reflection->GetMessage(c, outer);
      const pb::Descriptor* type = message.GetDescriptor();
      for (int j = 0; j < type->field_count(); ++j) {
        const pb::FieldDescriptor* field = type->field(j);
        const config::Range* range = SchemaRange(field);
        if (range == nullptr) continue;
        const int values =
            field->is_repeated() ? message.GetReflection()->FieldSize(message, field) : 1;
        for (int k = 0; k < values; ++k) {
          CheckRange(n, outer->name(), field->name(), NumericValue(message, field, k), range->min(),
                     range->max(), range->min_open(), outer->is_repeated() ? m : -1);
        }
      }
    }
  }
}

void CheckOrdered(const FieldNamer& namer, const std::string& message_field,
                  const std::string& min_field, double min, const std::string& max_field,
                  double max) {
  if (min > max) {
    throw ConfigError(namer.Where(message_field, max_field) + ": " + Number(max) + " is below " +
                      message_field + "." + min_field + " = " + Number(min));
  }
}

// the surface detail of a part (`index`) or of the bin (-1): a kind named
void CheckDetail(const FieldNamer& namer, const std::string& message_field, int index,
                 config::SurfaceDetail::Kind kind) {
  if (kind == config::SurfaceDetail::KIND_UNSPECIFIED) {
    throw ConfigError(namer.Where(message_field, "detail", index) +
                      ": must be NONE, CAST, BRUSHED, SCUFFED, MOULDED or WOOD");
  }
}

// fills the camera's size and intrinsics from its preset, keeping fields the file sets.
void ApplyCameraPreset(config::CameraConfig* camera, const FieldNamer& n) {
  if (camera->preset().empty()) return;
  const CameraPreset* preset = nullptr;
  std::string known;
  for (const CameraPreset& candidate : kCameraPresets) {
    if (camera->preset() == candidate.name) preset = &candidate;
    known += std::string(known.empty() ? "" : ", ") + candidate.name;
  }
  if (preset == nullptr) {
    throw ConfigError(n.Where("camera", "preset") + ": unknown camera '" + camera->preset() +
                      "'; known: " + known);
  }
  // (before the focal length in pixels is made of it)
  CheckSchemaRange(n, "camera", "lens_focal_length_mm", camera->lens_focal_length_mm());
  const double focal_px = camera->lens_focal_length_mm() * 1000.0 / preset->pixel_pitch_um;
  if (!camera->has_width()) camera->set_width(preset->width);
  if (!camera->has_height()) camera->set_height(preset->height);
  if (!camera->has_fx()) camera->set_fx(focal_px);
  if (!camera->has_fy()) camera->set_fy(focal_px);
}

// fills the 3D camera's fields from its preset, keeping fields the file sets (the field
// defaults are the structured-light preset).
void ApplySensor3dPreset(config::Sensor3dConfig* sensor, const FieldNamer& n) {
  if (sensor->preset() == "structured_light") return;
  if (sensor->preset() != "active_stereo") {
    throw ConfigError(n.Where("sensor_3d", "preset") + ": unknown 3D camera '" +
                      sensor->preset() + "'; known: structured_light, active_stereo");
  }
  if (!sensor->has_baseline_mm()) sensor->set_baseline_mm(55);
  if (!sensor->has_noise_at_1m_mm()) sensor->set_noise_at_1m_mm(1.6);
  if (!sensor->has_quantization_mm()) sensor->set_quantization_mm(1);
  if (!sensor->has_subsample()) sensor->set_subsample(2);
  if (!sensor->has_min_return()) sensor->set_min_return(0.01);
  if (!sensor->has_max_return()) sensor->set_max_return(50);
  if (!sensor->has_flying_pixel_probability()) sensor->set_flying_pixel_probability(0.8);
}

// the parts, and the objects a scene can hold
void ValidateParts(const config::GeneratorConfig& c, const FieldNamer& n) {
  // parts
  int max_objects = 0;
  bool any_part = false;
  for (int i = 0; i < c.part_size(); ++i) {
    const config::PartConfig& part = c.part(i);
    if (part.mesh().empty()) {
      throw ConfigError(n.Where("part", "mesh", i) + ": must name a mesh file");
    }
    if (part.class_name().empty()) {
      throw ConfigError(n.Where("part", "class_name", i) + ": must not be empty");
    }
    if (part.count_max() > 0) {
      CheckRange(n, "part", "count_min", part.count_min(), 0, part.count_max(), false, i);
      max_objects += part.count_max();
    } else {
      if (part.count_min() != 0) {
        throw ConfigError(n.Where("part", "count_min", i) +
                          ": needs count_max too (the number is drawn from [count_min, "
                          "count_max])");
      }
      max_objects += part.count();
    }
    CheckDetail(n, "part", i, part.detail());
    if (part.role() == config::PartConfig::ROLE_UNSPECIFIED) {
      throw ConfigError(n.Where("part", "role", i) +
                        ": must be PART, DISTRACTOR or LABELLED_DISTRACTOR");
    }
    any_part = any_part || part.role() == config::PartConfig::PART;
  }
  if (!any_part) throw ConfigError(n.Where("part", "role", 0) + ": no part has role PART");
  // annotation ids leave room for 999 instances per scene
  if (max_objects > 999) {
    throw ConfigError(n.Where("part", "count", 0) + ": up to " + std::to_string(max_objects) +
                      " objects per scene; at most 999");
  }
}

// the bin and its surroundings
void ValidateBin(const config::GeneratorConfig& c, const FieldNamer& n) {
  // bin
  const config::BinConfig& bin = c.bin();
  CheckDetail(n, "bin", -1, bin.detail());

  // surroundings
  const config::SurroundingsConfig& around = c.surroundings();
  CheckOrdered(n, "surroundings", "bin_roughness_min", around.bin_roughness_min(),
               "bin_roughness_max", around.bin_roughness_max());
  CheckOrdered(n, "surroundings", "bin_saturation_min", around.bin_saturation_min(),
               "bin_saturation_max", around.bin_saturation_max());
  CheckOrdered(n, "surroundings", "bin_value_min", around.bin_value_min(), "bin_value_max",
               around.bin_value_max());
  CheckOrdered(n, "surroundings", "table_value_min", around.table_value_min(),
               "table_value_max", around.table_value_max());
  if (around.metal_table_fraction() + around.wood_table_fraction() > 1 + 1e-9) {
    throw ConfigError(n.Where("surroundings", "wood_table_fraction") +
                      ": metal_table_fraction + wood_table_fraction is " +
                      std::to_string(around.metal_table_fraction() +
                                     around.wood_table_fraction()) +
                      ", more than 1");
  }
}

// the camera's own fields
void ValidateCameraFields(const config::GeneratorConfig& c, const FieldNamer& n) {
  // (the principal point within the image: its ranges depend on the size)
  const config::CameraConfig& camera = c.camera();
  if (camera.cx() >= 0) CheckRange(n, "camera", "cx", camera.cx(), 0, camera.width() - 1);
  if (camera.cy() >= 0) CheckRange(n, "camera", "cy", camera.cy(), 0, camera.height() - 1);
}

// the lights, none inside the bin
void ValidateLighting(const config::GeneratorConfig& c, const FieldNamer& n) {
  const config::BinConfig& bin = c.bin();
  // lighting and background
  const config::LightingConfig& light = c.lighting();
  CheckOrdered(n, "lighting", "ambient_min", light.ambient_min(), "ambient_max",
               light.ambient_max());
  CheckOrdered(n, "lighting", "diffuse_min", light.diffuse_min(), "diffuse_max",
               light.diffuse_max());
  CheckOrdered(n, "lighting", "specular_min", light.specular_min(), "specular_max",
               light.specular_max());
  CheckOrdered(n, "lighting", "count_min", light.count_min(), "count_max", light.count_max());
  CheckOrdered(n, "lighting", "distance_min_mm", light.distance_min_mm(), "distance_max_mm",
               light.distance_max_mm());
  CheckOrdered(n, "lighting", "light_radius_deg_min", light.light_radius_deg_min(),
               "light_radius_deg_max", light.light_radius_deg_max());
  if (light.color_temperature_min_k() != 0 || light.color_temperature_max_k() != 0) {
    // (0 and 0: no colour temperature drawn; else from the reddest the Planckian fit covers)
    constexpr double kReddestK = 1667;
    for (const auto& [field, value] :
         {std::make_pair("color_temperature_min_k", light.color_temperature_min_k()),
          std::make_pair("color_temperature_max_k", light.color_temperature_max_k())}) {
      if (value < kReddestK) {
        throw ConfigError(n.Where("lighting", field) + ": " + Number(value) +
                          " is out of range: 0 (with the other 0) or at least " +
                          Number(kReddestK));
      }
    }
    CheckOrdered(n, "lighting", "color_temperature_min_k", light.color_temperature_min_k(),
                 "color_temperature_max_k", light.color_temperature_max_k());
  }
  // a lamp inside the bin or the pile would light it from within
  const double bin_reach =
      std::sqrt(std::pow(bin.inner_length_mm() / 2 + bin.wall_thickness_mm(), 2) +
                std::pow(bin.inner_width_mm() / 2 + bin.wall_thickness_mm(), 2) +
                std::pow(bin.inner_height_mm(), 2));
  if (light.randomize() && light.point_fraction() > 0 && light.distance_min_mm() <= bin_reach) {
    throw ConfigError(n.Where("lighting", "distance_min_mm") + ": " +
                      Number(light.distance_min_mm()) +
                      " mm could put a point light inside the bin; it must exceed " +
                      Number(std::ceil(bin_reach)) + " mm (the farthest bin corner)");
  }
}

// appearance, background, sensor and rendering
void ValidateLook(const config::GeneratorConfig& c, const FieldNamer& n) {
  // appearance
  const config::AppearanceConfig& look = c.appearance();
  CheckOrdered(n, "appearance", "value_gain_min", look.value_gain_min(), "value_gain_max",
               look.value_gain_max());
  CheckOrdered(n, "appearance", "specular_gain_min", look.specular_gain_min(), "specular_gain_max",
               look.specular_gain_max());
  CheckOrdered(n, "appearance", "roughness_gain_min", look.roughness_gain_min(),
               "roughness_gain_max", look.roughness_gain_max());
  CheckOrdered(n, "appearance", "shininess_gain_min", look.shininess_gain_min(),
               "shininess_gain_max", look.shininess_gain_max());

  // background
  const config::BackgroundConfig& background = c.background();
  CheckOrdered(n, "background", "min", background.min(), "max", background.max());
  for (int i = 0; i < background.kind_size(); ++i) {
    if (background.kind(i) == config::BackgroundConfig::KIND_UNSPECIFIED) {
      throw ConfigError(n.Where("background", "kind") +
                        ": must be PLAIN, NOISE, STRIPES, CHECKER or IMAGE");
    }
    if (background.kind(i) == config::BackgroundConfig::IMAGE && background.image_dir().empty()) {
      throw ConfigError(n.Where("background", "kind") +
                        ": IMAGE needs background.image_dir, a folder of images");
    }
  }

  // sensor
  const config::SensorConfig& sensor = c.sensor();
  CheckOrdered(n, "sensor", "exposure_ev_min", sensor.exposure_ev_min(), "exposure_ev_max",
               sensor.exposure_ev_max());
  CheckOrdered(n, "sensor", "saturation_min", sensor.saturation_min(), "saturation_max",
               sensor.saturation_max());

  // rendering
  const config::RenderingConfig& rendering = c.rendering();
  if (rendering.shading() == config::RenderingConfig::SHADING_UNSPECIFIED) {
    throw ConfigError(n.Where("rendering", "shading") + ": must be PBR or PHONG");
  }
  const int samples = rendering.msaa_samples();
  if (samples != 1 && samples != 2 && samples != 4) {
    throw ConfigError(n.Where("rendering", "msaa_samples") + ": " + Number(samples) +
                      " must be 1, 2 or 4");
  }
  if (rendering.shading() == config::RenderingConfig::PBR && rendering.procedural_halls() == 0 &&
      rendering.environment_dir().empty()) {
    throw ConfigError(n.Where("rendering", "procedural_halls") +
                      ": 0 needs rendering.environment_dir, or PBR has no environment");
  }
  CheckOrdered(n, "rendering", "environment_intensity_min", rendering.environment_intensity_min(),
               "environment_intensity_max", rendering.environment_intensity_max());
  if (rendering.shading() == config::RenderingConfig::PHONG &&
      rendering.environment_occlusion_mm() > 0) {
    throw ConfigError(n.Where("rendering", "environment_occlusion_mm") +
                      ": needs shading: PBR (PHONG has no environment to hide)");
  }

  // the 3D camera
  const config::Sensor3dConfig& sensor_3d = c.sensor_3d();
  if (sensor_3d.enabled() && rendering.shading() != config::RenderingConfig::PBR) {
    throw ConfigError(n.Where("sensor_3d", "enabled") +
                      ": the 3D camera needs rendering.shading PBR (its dropout comes from the "
                      "physically based materials)");
  }
  const config::GraspConfig& grasps = c.grasps();
  if (grasps.tool_diameter_mm() < grasps.cup_diameter_mm()) {
    throw ConfigError(n.Where("grasps", "tool_diameter_mm") + ": " +
                      Number(grasps.tool_diameter_mm()) + " is below grasps.cup_diameter_mm = " +
                      Number(grasps.cup_diameter_mm()));
  }
  if (grasps.prove_per_part() > grasps.candidates_per_part()) {
    throw ConfigError(n.Where("grasps", "prove_per_part") + ": " +
                      Number(grasps.prove_per_part()) + " is above grasps.candidates_per_part = " +
                      Number(grasps.candidates_per_part()));
  }
  if (grasps.prove_per_part() > 0 && !grasps.suction() && !grasps.parallel_jaw()) {
    throw ConfigError(n.Where("grasps", "prove_per_part") +
                      ": proofs need grasps.suction or grasps.parallel_jaw true");
  }
  if (sensor_3d.baseline_mm() == 0) {
    throw ConfigError(n.Where("sensor_3d", "baseline_mm") +
                      ": must not be 0 (the projector cannot sit in the camera)");
  }
}

// the simulation and the drops
void ValidatePhysics(const config::GeneratorConfig& c, const FieldNamer& n) {
  const config::BinConfig& bin = c.bin();
  // physics
  const config::PhysicsConfig& physics = c.physics();
  // (the ranges of time_step_s: coarser steps let 6 mm plates tunnel through each other)
  CheckOrdered(n, "physics", "time_step_s", physics.time_step_s(), "rest_time_step_s",
               physics.rest_time_step_s());
  CheckOrdered(n, "physics", "time_step_s", physics.time_step_s(), "settle_window_s",
               physics.settle_window_s());
  CheckOrdered(n, "physics", "settle_window_s", physics.settle_window_s(), "max_sim_time_s",
               physics.max_sim_time_s());
  if (physics.drop_mode() == config::PhysicsConfig::DROP_MODE_UNSPECIFIED) {
    throw ConfigError(n.Where("physics", "drop_mode") +
                      ": must be RANDOM_VOLUME, SEQUENTIAL or CUT_AND_PASTE");
  }
  if (physics.drop_mode() == config::PhysicsConfig::CUT_AND_PASTE && physics.pick_sequence()) {
    throw ConfigError(n.Where("physics", "pick_sequence") +
                      ": a cut-and-paste scene has no pile to pick from (drop_mode "
                      "CUT_AND_PASTE)");
  }
  CheckRange(n, "physics", "drop_point_x_mm", physics.drop_point_x_mm(), -bin.inner_length_mm() / 2,
             bin.inner_length_mm() / 2);
  CheckRange(n, "physics", "drop_point_y_mm", physics.drop_point_y_mm(), -bin.inner_width_mm() / 2,
             bin.inner_width_mm() / 2);
}

// annotation and output
void ValidateOutput(const config::GeneratorConfig& c, const FieldNamer& n) {
  // annotation and output
  if (c.annotation().occlusion_rule() == config::AnnotationConfig::OCCLUSION_RULE_UNSPECIFIED) {
    throw ConfigError(n.Where("annotation", "occlusion_rule") + ": must be DROP or IGNORE");
  }
  if (c.output().image_encoding() == config::OutputConfig::ENCODING_UNSPECIFIED) {
    throw ConfigError(n.Where("output", "image_encoding") + ": must be RAW or PNG");
  }
}

// what the camera sees of the bin: above the rim, within the depth range, the whole interior
void ValidateView(const config::GeneratorConfig& c, const FieldNamer& n) {
  const config::BinConfig& bin = c.bin();
  const config::CameraConfig& camera = c.camera();
  // the camera must stay above the rim in every drawn pose, and its nominal pose see the whole
  // bin interior.
  const double lowest_mm = (camera.height_mm() - camera.distance_jitter_mm()) *
                           std::cos(camera.tilt_max_deg() * M_PI / 180);
  if (lowest_mm <= bin.inner_height_mm()) {
    throw ConfigError(n.Where("camera", "height_mm") + ": " + Number(camera.height_mm()) +
                      " mm (less distance_jitter_mm " + Number(camera.distance_jitter_mm()) +
                      ", tilted by up to tilt_max_deg " + Number(camera.tilt_max_deg()) +
                      ") can put the camera at " + Number(lowest_mm) +
                      " mm, not above the bin rim at " + Number(bin.inner_height_mm()) + " mm");
  }
  // the farthest surface in view must fit the 16-bit depth image
  const double farthest_mm = camera.height_mm() + camera.distance_jitter_mm() +
                             std::hypot(bin.inner_length_mm(), bin.inner_width_mm()) +
                             2 * bin.wall_thickness_mm();
  if (farthest_mm > 65535 * camera.depth_scale_mm()) {
    throw ConfigError(n.Where("camera", "depth_scale_mm") + ": " + Number(camera.depth_scale_mm()) +
                      " mm per count reaches " + Number(65535 * camera.depth_scale_mm()) +
                      " mm, but surfaces in view can be up to " + Number(farthest_mm) +
                      " mm away; raise depth_scale_mm");
  }
  const Eigen::Isometry3d camera_from_world = WorldFromCamera(camera).inverse();
  const Eigen::Vector2d principal = PrincipalPoint(camera);
  const double half_l = bin.inner_length_mm() / 2;
  const double half_w = bin.inner_width_mm() / 2;
  for (const double z : {0.0, bin.inner_height_mm()}) {
    for (const double sx : {-1.0, 1.0}) {
      for (const double sy : {-1.0, 1.0}) {
        const Eigen::Vector3d p = camera_from_world * Eigen::Vector3d(sx * half_l, sy * half_w, z);
        const double u = camera.fx() * p.x() / p.z() + principal.x();
        const double v = camera.fy() * p.y() / p.z() + principal.y();
        if (u < 0 || v < 0 || u > camera.width() - 1 || v > camera.height() - 1) {
          throw ConfigError(n.Where("camera", "height_mm") + ": the camera (" +
                            std::to_string(camera.width()) + "x" + std::to_string(camera.height()) +
                            ", fx " + Number(camera.fx()) + ", " + Number(camera.height_mm()) +
                            " mm above the floor) cannot see the whole bin: corner (" +
                            Number(sx * half_l) + ", " + Number(sy * half_w) + ", " + Number(z) +
                            ") mm falls outside the image; raise height_mm or lower fx/fy" +
                            (camera.preset().empty() ? "" : " (lens_focal_length_mm)"));
        }
      }
    }
  }
}

// every field and every setting that cannot work: the ranges first, then what depends on other
// fields, in the order a reader meets them
void Validate(const config::GeneratorConfig& c, const FieldNamer& n) {
  CheckFieldRanges(c, n);
  ValidateParts(c, n);
  ValidateBin(c, n);
  ValidateCameraFields(c, n);
  ValidateLighting(c, n);
  ValidateLook(c, n);
  ValidatePhysics(c, n);
  ValidateOutput(c, n);
  ValidateView(c, n);
}

}  // namespace

std::string LoadedConfig::Resolve(const std::string& relative) const {
  if (relative.empty() || relative[0] == '/' || base_dir.empty()) return relative;
  return base_dir + "/" + relative;
}

LoadedConfig ParseConfig(const std::string& text, const std::string& name,
                         const std::string& base_dir) {
  LoadedConfig loaded;
  loaded.path = name;
  loaded.base_dir = base_dir;

  // parse, refusing unknown fields, and keep where each field was set.
  pb::TextFormat::Parser parser;
  ErrorCollector errors(name);
  pb::TextFormat::ParseInfoTree tree;
  parser.RecordErrorsTo(&errors);
  parser.WriteLocationsTo(&tree);
  if (!parser.ParseFromString(text, &loaded.config)) {
    throw ConfigError(errors.first().empty() ? name + ": cannot parse the config" : errors.first());
  }
  // no part block: one default part, the built-in connector
  if (loaded.config.part_size() == 0) loaded.config.add_part();
  // a part without a class_name is named after its mesh file: "parts/bracket_v2.stl" is
  // "bracket_v2" (the built-in connector's file gives "corner_connector")
  for (config::PartConfig& part : *loaded.config.mutable_part()) {
    loaded.class_from_file.push_back(!part.has_class_name());
    if (!part.has_class_name()) {
      part.set_class_name(std::filesystem::path(part.mesh()).stem().string());
    }
  }
  const FieldNamer namer(name, &tree);
  ApplyCameraPreset(loaded.config.mutable_camera(), namer);
  ApplySensor3dPreset(loaded.config.mutable_sensor_3d(), namer);
  Validate(loaded.config, namer);
  return loaded;
}

LoadedConfig LoadConfig(const std::string& path) {
  // (an ifstream opens a folder and reads it as an empty config: all defaults)
  std::error_code error;
  const std::filesystem::file_status status = std::filesystem::status(path, error);
  if (std::filesystem::is_directory(status)) {
    throw ConfigError(path + ": is a folder, not a config file (protobuf text, e.g. " +
                      "config/default.pbtxt)");
  }
  if (!std::filesystem::exists(status)) {
    throw ConfigError(path + ": cannot read the config file: no such file");
  }
  std::ifstream file(path);
  if (!file) throw ConfigError(path + ": cannot read the config file");
  std::ostringstream text;
  text << file.rdbuf();
  if (file.bad()) throw ConfigError(path + ": cannot read the config file");
  const size_t slash = path.find_last_of('/');
  return ParseConfig(text.str(), path, slash == std::string::npos ? "." : path.substr(0, slash));
}

std::string EffectiveConfigText(const config::GeneratorConfig& config) {
  // fill every default in, recursively, so the published text says everything.
  config::GeneratorConfig full = config;
  std::vector<pb::Message*> pending = {&full};
  while (!pending.empty()) {
    pb::Message* message = pending.back();
    pending.pop_back();
    const pb::Reflection* reflection = message->GetReflection();
    const pb::Descriptor* descriptor = message->GetDescriptor();
    for (int i = 0; i < descriptor->field_count(); ++i) {
      const pb::FieldDescriptor* field = descriptor->field(i);
      if (field->is_repeated()) {
        if (field->cpp_type() == pb::FieldDescriptor::CPPTYPE_MESSAGE) {
          for (int k = 0; k < reflection->FieldSize(*message, field); ++k) {
            pending.push_back(reflection->MutableRepeatedMessage(message, field, k));
          }
        }
        continue;
      }
      if (field->cpp_type() == pb::FieldDescriptor::CPPTYPE_MESSAGE) {
        pending.push_back(reflection->MutableMessage(message, field));
        continue;
      }
      if (reflection->HasField(*message, field)) continue;
      switch (field->cpp_type()) {
        case pb::FieldDescriptor::CPPTYPE_INT32:
          reflection->SetInt32(message, field, field->default_value_int32());
          break;
        case pb::FieldDescriptor::CPPTYPE_DOUBLE:
          reflection->SetDouble(message, field, field->default_value_double());
          break;
        case pb::FieldDescriptor::CPPTYPE_BOOL:
          reflection->SetBool(message, field, field->default_value_bool());
          break;
        case pb::FieldDescriptor::CPPTYPE_STRING:
          reflection->SetString(message, field, field->default_value_string());
          break;
        case pb::FieldDescriptor::CPPTYPE_ENUM:
          reflection->SetEnum(message, field, field->default_value_enum());
          break;
        default:
          break;
      }
    }
  }
  std::string text;
  pb::TextFormat::PrintToString(full, &text);
  return text;
}

Eigen::Isometry3d WorldFromCamera(const config::CameraConfig& camera) {
  Eigen::Isometry3d world_from_camera = Eigen::Isometry3d::Identity();
  Eigen::Matrix3d rotation;
  // columns: the camera's x, y, z axes in the world frame (looking down, image up = world +y).
  rotation << 1, 0, 0,  //
      0, -1, 0,         //
      0, 0, -1;
  world_from_camera.linear() = rotation;
  world_from_camera.translation() = Eigen::Vector3d(0, 0, camera.height_mm());
  return world_from_camera;
}

Eigen::Vector2d PrincipalPoint(const config::CameraConfig& camera) {
  return {camera.cx() >= 0 ? camera.cx() : (camera.width() - 1) / 2.0,
          camera.cy() >= 0 ? camera.cy() : (camera.height() - 1) / 2.0};
}

std::string DefaultConfigPath(const std::string& built_in) {
  std::error_code error;
  const std::filesystem::path program = std::filesystem::read_symlink("/proc/self/exe", error);
  if (error) return built_in;
  const std::filesystem::path installed =
      program.parent_path().parent_path() / "share/stackgen/config/default.pbtxt";
  return std::filesystem::exists(installed, error) ? installed.string() : built_in;
}

}  // namespace stackgen
