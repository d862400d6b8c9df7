#include "gen/config/config.h"

#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

namespace stackgen {
namespace {

// the message of the ConfigError that parsing `text` throws, or "" when it parses.
std::string ErrorOf(const std::string& text) {
  try {
    ParseConfig(text, "test.pbtxt", "/configs");
  } catch (const ConfigError& error) {
    return error.what();
  }
  return "";
}

// the shipped configs parse and validate.
TEST(ConfigTest, ShippedConfigsAreValid) {
  for (const char* name :
       {"default.pbtxt", "tote.pbtxt", "mixed.pbtxt", "tapered_tote.pbtxt", "basler.pbtxt",
        "ignore_occluded.pbtxt", "phong.pbtxt", "studio_hdri.pbtxt", "cut_and_paste.pbtxt",
        "ablation/none.pbtxt", "ablation/no_background.pbtxt", "ablation/no_lighting.pbtxt",
        "ablation/no_noise.pbtxt", "ablation/no_occlusion_filter.pbtxt", "surroundings.pbtxt",
        "picking.pbtxt"}) {
    const LoadedConfig loaded = LoadConfig(std::string(STACKGEN_SOURCE_DIR) + "/config/" + name);
    EXPECT_GT(loaded.config.part(0).count(), 0) << name;
  }
}

// the 3D camera: off by default; a preset fills the fields the file leaves out; an unknown
// preset, a projector in the camera and Phong shading are refused, naming the field
TEST(ConfigTest, Sensor3dPresetsAndChecks) {
  const LoadedConfig plain = ParseConfig("", "test.pbtxt", "/configs");
  EXPECT_FALSE(plain.config.sensor_3d().enabled());
  EXPECT_DOUBLE_EQ(plain.config.sensor_3d().baseline_mm(), 120);
  const LoadedConfig stereo = ParseConfig(
      "sensor_3d { enabled: true preset: \"active_stereo\" noise_at_1m_mm: 3 }", "test.pbtxt",
      "/configs");
  EXPECT_DOUBLE_EQ(stereo.config.sensor_3d().baseline_mm(), 55);
  EXPECT_EQ(stereo.config.sensor_3d().subsample(), 2);
  EXPECT_DOUBLE_EQ(stereo.config.sensor_3d().noise_at_1m_mm(), 3);
  EXPECT_EQ(ErrorOf("sensor_3d { preset: \"kinect\" }"),
            "test.pbtxt:1: sensor_3d.preset: unknown 3D camera 'kinect'; known: "
            "structured_light, active_stereo");
  EXPECT_EQ(ErrorOf("sensor_3d { enabled: true baseline_mm: 0 }"),
            "test.pbtxt:1: sensor_3d.baseline_mm: must not be 0 (the projector cannot sit in the "
            "camera)");
  EXPECT_EQ(ErrorOf("rendering { shading: PHONG }\nsensor_3d { enabled: true }"),
            "test.pbtxt:2: sensor_3d.enabled: the 3D camera needs rendering.shading PBR (its "
            "dropout comes from the physically based materials)");
  EXPECT_NE(ErrorOf("sensor_3d { subsample: 0 }").find("sensor_3d.subsample"), std::string::npos);
}

// an empty config takes the documented defaults, and relative paths resolve to its folder.
TEST(ConfigTest, DefaultsAndPaths) {
  const LoadedConfig loaded = ParseConfig("", "test.pbtxt", "/configs");
  EXPECT_EQ(loaded.config.part(0).count(), 12);
  EXPECT_DOUBLE_EQ(loaded.config.part(0).density_kg_m3(), 2700);
  EXPECT_DOUBLE_EQ(loaded.config.annotation().min_visib_fract(), 0.3);
  EXPECT_EQ(loaded.Resolve("models/a.obj"), "/configs/models/a.obj");
  EXPECT_EQ(loaded.Resolve("/abs/a.obj"), "/abs/a.obj");
  EXPECT_EQ(loaded.config.part(0).class_name(), "corner_connector");
}

// a part without a class_name is labelled after its mesh file, not after the built-in part;
// one that names its class keeps it, and --check can say which was which.
TEST(ConfigTest, ClassNameDefaultsToTheMeshFilesName) {
  const LoadedConfig loaded = ParseConfig(
      "part { mesh: \"parts/bracket_v2.stl\" }\n"
      "part { mesh: \"pin.obj\" class_name: \"dowel\" }\n",
      "test.pbtxt", "/configs");
  EXPECT_EQ(loaded.config.part(0).class_name(), "bracket_v2");
  EXPECT_EQ(loaded.config.part(1).class_name(), "dowel");
  EXPECT_EQ(loaded.class_from_file, (std::vector<bool>{true, false}));
  EXPECT_EQ(ErrorOf("part { mesh: \"a.obj\" class_name: \"\" }"),
            "test.pbtxt:1: part[0].class_name: must not be empty");
}

// the rendering settings are checked before anything runs, naming the field
TEST(ConfigTest, RenderingFieldsAreChecked) {
  const auto error = [](const std::string& text) {
    try {
      ParseConfig(text, "test.pbtxt", "/configs");
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(ParseConfig("", "test.pbtxt", "/configs").config.rendering().shading(),
            config::RenderingConfig::PBR);
  EXPECT_NE(error("rendering { msaa_samples: 3 }").find("rendering.msaa_samples"),
            std::string::npos);
  EXPECT_NE(error("rendering { procedural_halls: 0 }").find("rendering.procedural_halls"),
            std::string::npos);
  EXPECT_EQ(error("rendering { shading: PHONG procedural_halls: 0 }"), "");
  EXPECT_NE(error("rendering { shading: PHONG environment_occlusion_mm: 200 }")
                .find("rendering.environment_occlusion_mm"),
            std::string::npos);
  EXPECT_NE(error("rendering { environment_occlusion_mm: -1 }")
                .find("rendering.environment_occlusion_mm"),
            std::string::npos);
  EXPECT_EQ(error("rendering { environment_occlusion_mm: 200 }"), "");
  EXPECT_NE(error("part { roughness: 1.5 }").find("part[0].roughness"), std::string::npos);
  EXPECT_NE(
      error("sensor { exposure_ev_min: 1 exposure_ev_max: 0 }").find("sensor.exposure_ev_max"),
      std::string::npos);
  EXPECT_NE(
      error("sensor { saturation_min: 1.5 saturation_max: 1 }").find("sensor.saturation_max"),
      std::string::npos);
  EXPECT_NE(error("sensor { saturation_max: 2.5 }").find("sensor.saturation_max"),
            std::string::npos);
  // surface detail and surroundings
  EXPECT_NE(error("part { detail: CAST detail_scale_mm: 0 }").find("part[0].detail_scale_mm"),
            std::string::npos);
  EXPECT_NE(error("bin { detail_strength: 2 }").find("bin.detail_strength"), std::string::npos);
  EXPECT_NE(error("surroundings { table_probability: 1.5 }").find("surroundings.table_probability"),
            std::string::npos);
  EXPECT_NE(error("surroundings { bin_roughness_min: 0.8 bin_roughness_max: 0.5 }")
                .find("surroundings.bin_roughness_max"),
            std::string::npos);
  EXPECT_EQ(error("part { detail: BRUSHED } bin { detail: SCUFFED } "
                  "surroundings { table_probability: 1 }"),
            "");
  // the wider totes and tables, the ring light and the white balance
  EXPECT_NE(error("surroundings { bin_value_min: 0.9 bin_value_max: 0.5 }")
                .find("surroundings.bin_value_max"),
            std::string::npos);
  EXPECT_NE(error("surroundings { bin_saturation_max: 1.2 }").find("surroundings.bin_saturation_max"),
            std::string::npos);
  EXPECT_NE(error("surroundings { metal_table_fraction: 0.6 wood_table_fraction: 0.6 }")
                .find("surroundings.wood_table_fraction"),
            std::string::npos);
  EXPECT_NE(error("lighting { camera_light_probability: -0.1 }")
                .find("lighting.camera_light_probability"),
            std::string::npos);
  EXPECT_NE(error("sensor { white_balance_max: 0.7 }").find("sensor.white_balance_max"),
            std::string::npos);
  EXPECT_NE(error("sensor { clipped_tone_probability: 2 }").find("sensor.clipped_tone_probability"),
            std::string::npos);
  EXPECT_EQ(error("bin { detail: WOOD } surroundings { metal_table_fraction: 0.5 "
                  "wood_table_fraction: 0.5 table_saturation_max: 1 } lighting { "
                  "camera_light_probability: 1 } sensor { white_balance_max: 0.5 }"),
            "");
}

// an unknown field is refused with the file, line and field name.
TEST(ConfigTest, UnknownFieldNamesFileAndLine) {
  const std::string error = ErrorOf("part {\n  count: 3\n  colour: 1\n}\n");
  EXPECT_NE(error.find("test.pbtxt:3:"), std::string::npos) << error;
  EXPECT_NE(error.find("colour"), std::string::npos) << error;
}

// an out-of-range value names the file, its line and the dotted field.
TEST(ConfigTest, OutOfRangeNamesLineAndField) {
  const std::string error = ErrorOf("bin {\n  inner_length_mm: 200\n  inner_width_mm: -5\n}\n");
  EXPECT_NE(error.find("test.pbtxt:3: bin.inner_width_mm"), std::string::npos) << error;
  EXPECT_NE(ErrorOf("part { count: -1 }").find("part[0].count"), std::string::npos);
  EXPECT_NE(ErrorOf("part { count: 0 }").find("part[0].count"), std::string::npos);
}

// several part blocks: an error names the block by index and its line.
TEST(ConfigTest, SeveralPartsNameTheBlock) {
  const std::string error =
      ErrorOf("part { count: 3 }\npart {\n  mesh: \"b.obj\"\n  friction: 7\n}\n");
  EXPECT_NE(error.find("test.pbtxt:4: part[1].friction"), std::string::npos) << error;
  const LoadedConfig loaded = ParseConfig(
      "part { count: 3 }\npart { count_min: 0 count_max: 4 role: DISTRACTOR }", "test.pbtxt", ".");
  ASSERT_EQ(loaded.config.part_size(), 2);
  EXPECT_EQ(loaded.config.part(1).role(), config::PartConfig::DISTRACTOR);
  // no part block at all: one default part, the built-in connector
  const LoadedConfig plain = ParseConfig("", "test.pbtxt", ".");
  ASSERT_EQ(plain.config.part_size(), 1);
  EXPECT_EQ(plain.config.part(0).mesh(), "models/corner_connector.obj");
}

// count ranges, roles and drop settings that cannot work are refused, naming the field.
TEST(ConfigTest, CountRangeRoleAndDropChecks) {
  EXPECT_NE(ErrorOf("part { count_min: 2 }").find("part[0].count_min"), std::string::npos);
  EXPECT_NE(ErrorOf("part { count_min: 5 count_max: 4 }").find("part[0].count_min"),
            std::string::npos);
  EXPECT_NE(ErrorOf("part { role: DISTRACTOR }").find("no part has role PART"), std::string::npos);
  EXPECT_NE(ErrorOf("part { count: 600 }\npart { count: 600 }").find("at most 999"),
            std::string::npos);
  EXPECT_NE(ErrorOf("physics { drop_point_x_mm: 150 }").find("physics.drop_point_x_mm"),
            std::string::npos);
  EXPECT_NE(ErrorOf("physics { max_penetration_mm: 0 }").find("physics.max_penetration_mm"),
            std::string::npos);
  EXPECT_NE(ErrorOf("part { rolling_friction_mm: -1 }").find("part[0].rolling_friction_mm"),
            std::string::npos);
  EXPECT_NE(ErrorOf("physics { views_per_pile: 0 }").find("physics.views_per_pile"),
            std::string::npos);
  EXPECT_NE(ErrorOf("physics { solver_iterations: 4 }").find("physics.solver_iterations"),
            std::string::npos);
  EXPECT_EQ(ErrorOf("physics { solver_iterations: 20 }"), "");
  EXPECT_EQ(ErrorOf("physics { free_friction_while_falling: false }"), "");
}

// min above max is refused.
TEST(ConfigTest, MinAboveMax) {
  const std::string error = ErrorOf("lighting { ambient_min: 0.5 ambient_max: 0.2 }");
  EXPECT_NE(error.find("lighting.ambient_max"), std::string::npos) << error;
}

// a camera that cannot see the whole bin, or sits below its rim, is refused.
TEST(ConfigTest, CameraMustSeeTheBin) {
  EXPECT_NE(ErrorOf("camera { height_mm: 200 fx: 2000 fy: 2000 }").find("cannot see"),
            std::string::npos);
  EXPECT_NE(ErrorOf("camera { height_mm: 50 }").find("not above the bin rim"), std::string::npos)
      << ErrorOf("camera { height_mm: 50 }");
}

// a camera preset sets the sensor size and focal length from its pixel pitch and lens; fields
// the file sets win, and an unknown preset lists the known ones.
TEST(ConfigTest, CameraPreset) {
  const LoadedConfig basler = ParseConfig(
      "camera { preset: \"basler_scA1600-20gc\" lens_focal_length_mm: 8.8 }", "test.pbtxt", ".");
  EXPECT_EQ(basler.config.camera().width(), 1626);
  EXPECT_EQ(basler.config.camera().height(), 1236);
  EXPECT_DOUBLE_EQ(basler.config.camera().fx(), 2000);  // 8.8 mm / 4.4 um
  EXPECT_DOUBLE_EQ(basler.config.camera().fy(), 2000);
  EXPECT_DOUBLE_EQ(PrincipalPoint(basler.config.camera()).x(), 812.5);
  const LoadedConfig overridden = ParseConfig(
      "camera { preset: \"basler_scA1600-20gc\" width: 1600 fx: 1500 }", "test.pbtxt", ".");
  EXPECT_EQ(overridden.config.camera().width(), 1600);
  EXPECT_EQ(overridden.config.camera().height(), 1236);
  EXPECT_DOUBLE_EQ(overridden.config.camera().fx(), 1500);
  EXPECT_DOUBLE_EQ(overridden.config.camera().fy(), 8 * 1000 / 4.4);
  const std::string error = ErrorOf("camera {\n  preset: \"acme_cam\"\n}");
  EXPECT_NE(error.find("test.pbtxt:2: camera.preset"), std::string::npos) << error;
  EXPECT_NE(error.find("basler_scA1600-20gc"), std::string::npos) << error;
  // a preset camera too close to see the bin names the lens
  EXPECT_NE(ErrorOf("camera { preset: \"basler_scA1600-20gc\" lens_focal_length_mm: 25 }")
                .find("lens_focal_length_mm"),
            std::string::npos);
}

// randomisation ranges that cannot work are refused, naming the field.
TEST(ConfigTest, RandomisationChecks) {
  EXPECT_NE(ErrorOf("lighting { count_max: 4 }").find("lighting.count_max"), std::string::npos);
  EXPECT_NE(ErrorOf("lighting { count_min: 3 count_max: 2 }").find("lighting.count_max"),
            std::string::npos);
  EXPECT_NE(ErrorOf("lighting { distance_min_mm: 100 }").find("inside the bin"), std::string::npos);
  EXPECT_NE(ErrorOf("background { kind: IMAGE }").find("background.image_dir"), std::string::npos);
  EXPECT_NE(ErrorOf("sensor { salt_pepper_max: 0.5 }").find("sensor.salt_pepper_max"),
            std::string::npos);
  EXPECT_NE(ErrorOf("appearance { value_gain_min: 2 }").find("appearance.value_gain_max"),
            std::string::npos);
  EXPECT_NE(ErrorOf("camera { roll_max_deg: 200 }").find("camera.roll_max_deg"), std::string::npos);
  // a tilted, closer camera could end up below the rim
  EXPECT_NE(ErrorOf("camera { height_mm: 140 distance_jitter_mm: 40 tilt_max_deg: 30 fx: 200 "
                    "fy: 200 }")
                .find("not above the bin rim"),
            std::string::npos);
  // depth beyond 16 bits of depth_scale_mm
  EXPECT_NE(ErrorOf("camera { depth_scale_mm: 0.005 }").find("camera.depth_scale_mm"),
            std::string::npos);
  EXPECT_NE(ErrorOf("annotation { occlusion_rule: OCCLUSION_RULE_UNSPECIFIED }")
                .find("annotation.occlusion_rule"),
            std::string::npos);
  const LoadedConfig ignore =
      ParseConfig("annotation { occlusion_rule: IGNORE }", "test.pbtxt", ".");
  EXPECT_EQ(ignore.config.annotation().occlusion_rule(), config::AnnotationConfig::IGNORE);
}

// a syntax error names the file and line.
TEST(ConfigTest, SyntaxError) {
  const std::string error = ErrorOf("part {\n count: 3\n");
  EXPECT_NE(error.find("test.pbtxt:"), std::string::npos) << error;
}

// the effective text writes every default out and parses back to the same config.
TEST(ConfigTest, EffectiveTextRoundTrips) {
  const LoadedConfig loaded = ParseConfig("part { count: 5 }", "test.pbtxt", ".");
  const std::string text = EffectiveConfigText(loaded.config);
  EXPECT_NE(text.find("density_kg_m3: 2700"), std::string::npos) << text;
  EXPECT_NE(text.find("count: 5"), std::string::npos) << text;
  const LoadedConfig again = ParseConfig(text, "again.pbtxt", ".");
  EXPECT_EQ(again.config.part(0).count(), 5);
  EXPECT_EQ(EffectiveConfigText(again.config), text);
  // a count range survives the round trip too
  const LoadedConfig ranged = ParseConfig("part { count_min: 2 count_max: 7 }", "r.pbtxt", ".");
  const LoadedConfig ranged_again =
      ParseConfig(EffectiveConfigText(ranged.config), "again.pbtxt", ".");
  EXPECT_EQ(ranged_again.config.part(0).count_max(), 7);
  EXPECT_EQ(ranged_again.config.part(0).count_min(), 2);
}

// the camera looks straight down: the bin centre projects to the principal point.
TEST(ConfigTest, CameraLooksDown) {
  const LoadedConfig loaded = ParseConfig("", "test.pbtxt", ".");
  const Eigen::Isometry3d camera_from_world = WorldFromCamera(loaded.config.camera()).inverse();
  const Eigen::Vector3d floor_centre = camera_from_world * Eigen::Vector3d::Zero();
  EXPECT_NEAR(floor_centre.x(), 0, 1e-9);
  EXPECT_NEAR(floor_centre.y(), 0, 1e-9);
  EXPECT_NEAR(floor_centre.z(), 450, 1e-9);
  // world +y is up in the image (camera -y).
  const Eigen::Vector3d plus_y = camera_from_world * Eigen::Vector3d(0, 10, 0);
  EXPECT_LT(plus_y.y(), 0);
}

// Lamps' sizes: 0..45 degrees, the smaller first.
TEST(ConfigTest, LightRadiiInRangeAndOrdered) {
  EXPECT_EQ(ErrorOf("lighting { light_radius_deg_min: 0.5 light_radius_deg_max: 25 }"), "");
  const std::string order =
      ErrorOf("lighting { light_radius_deg_min: 20 light_radius_deg_max: 10 }");
  EXPECT_NE(order.find("lighting.light_radius_deg_max: 10 is below"), std::string::npos) << order;
  const std::string wide = ErrorOf("lighting { light_radius_deg_max: 50 }");
  EXPECT_NE(wide.find("lighting.light_radius_deg_max: 50 is out of range"), std::string::npos)
      << wide;
}

// Colour temperatures: both 0 (white lights) or both from 1667 K on, the lower first.
TEST(ConfigTest, ColourTemperaturesAreOffOrFromTheReddest) {
  EXPECT_EQ(ErrorOf("lighting { color_temperature_min_k: 0 color_temperature_max_k: 0 }"), "");
  EXPECT_EQ(ErrorOf("lighting { color_temperature_min_k: 2700 color_temperature_max_k: 6500 }"),
            "");
  const std::string low =
      ErrorOf("lighting { color_temperature_min_k: 1000 color_temperature_max_k: 6500 }");
  EXPECT_NE(low.find("lighting.color_temperature_min_k: 1000 is out of range"), std::string::npos)
      << low;
  const std::string half = ErrorOf("lighting { color_temperature_max_k: 6500 }");
  EXPECT_NE(half.find("lighting.color_temperature_min_k (default): 0 is out of range"),
            std::string::npos)
      << half;
  const std::string order =
      ErrorOf("lighting { color_temperature_min_k: 6500 color_temperature_max_k: 2700 }");
  EXPECT_NE(order.find("lighting.color_temperature_max_k: 2700 is below"), std::string::npos)
      << order;
}

// Every number of the schema (each numeric field of each message a config holds) states its
// range once, as the (range) option of types/stackgen_config.proto, and its default keeps it.
TEST(ConfigSchemaTest, EveryNumberStatesItsRangeAndItsDefaultKeepsIt) {
  namespace pb = google::protobuf;
  const pb::Descriptor* root = config::GeneratorConfig::descriptor();
  int numbers = 0;
  for (int i = 0; i < root->field_count(); ++i) {
    const pb::Descriptor* type = root->field(i)->message_type();
    ASSERT_NE(type, nullptr) << root->field(i)->name();
    for (int j = 0; j < type->field_count(); ++j) {
      const pb::FieldDescriptor* field = type->field(j);
      const auto kind = field->cpp_type();
      if (kind == pb::FieldDescriptor::CPPTYPE_STRING ||
          kind == pb::FieldDescriptor::CPPTYPE_BOOL || kind == pb::FieldDescriptor::CPPTYPE_ENUM) {
        EXPECT_FALSE(field->options().HasExtension(config::range)) << field->full_name();
        continue;
      }
      ++numbers;
      ASSERT_TRUE(field->options().HasExtension(config::range))
          << field->full_name() << " states no (range)";
      const config::Range& range = field->options().GetExtension(config::range);
      ASSERT_TRUE(range.has_min() && range.has_max()) << field->full_name();
      double value = 0;
      switch (kind) {
        case pb::FieldDescriptor::CPPTYPE_DOUBLE:
          value = field->default_value_double();
          break;
        case pb::FieldDescriptor::CPPTYPE_FLOAT:
          value = field->default_value_float();
          break;
        case pb::FieldDescriptor::CPPTYPE_INT32:
          value = field->default_value_int32();
          break;
        default:
          FAIL() << "a number of another type: " << field->full_name();
      }
      if (field->is_repeated()) continue;  // (no default)
      EXPECT_TRUE((range.min_open() ? value > range.min() : value >= range.min()) &&
                  value <= range.max())
          << field->full_name() << ": default " << value << " outside its range";
    }
  }
  EXPECT_GT(numbers, 100);
}

// The validator knows every stated range: a value just outside it, in a config that is fine
// otherwise, is refused with a line naming the field.
TEST(ConfigSchemaTest, TheValidatorRefusesAValueJustOutsideEveryRange) {
  namespace pb = google::protobuf;
  const pb::Descriptor* root = config::GeneratorConfig::descriptor();
  int checked = 0;
  for (int i = 0; i < root->field_count(); ++i) {
    const pb::FieldDescriptor* outer = root->field(i);
    const pb::Descriptor* type = outer->message_type();
    for (int j = 0; j < type->field_count(); ++j) {
      const pb::FieldDescriptor* field = type->field(j);
      if (!field->options().HasExtension(config::range)) continue;
      const config::Range& range = field->options().GetExtension(config::range);
      const bool integer = field->cpp_type() == pb::FieldDescriptor::CPPTYPE_INT32;
      for (const double outside :
           {range.min_open() ? range.min() : range.min() - 1,
            range.max() + (integer ? 1 : 1e-3 * std::max(1.0, std::abs(range.max())))}) {
        std::ostringstream text;
        text.precision(17);
        text << outer->name() << " { " << field->name() << ": " << outside << " }";
        const std::string error = ErrorOf(text.str());
        const std::string named =
            outer->name() + (outer->is_repeated() ? "[0]." : ".") + field->name() + ": ";
        EXPECT_NE(error.find(named), std::string::npos) << text.str() << " -> " << error;
        EXPECT_NE(error.find("out of range"), std::string::npos) << text.str() << " -> " << error;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 200);
}

}  // namespace
}  // namespace stackgen
