#pragma once

#include <random>

#include <Eigen/Core>

#include "stackgen_config.pb.h"

namespace stackgen {

/// What a scene's surroundings look like (config SurroundingsConfig), drawn from its engine.
struct DrawnSurroundings {
  /// The bin's colour (display values), metallic and roughness replace the configured ones.
  bool bin_restyled = false;
  Eigen::Vector3f bin_color{0, 0, 0};
  float bin_metallic = 0;
  float bin_roughness = 0;
  /// Dust and scuff marks on the bin, of this strength (0..1).
  bool bin_scuffed = false;
  float bin_scuff_strength = 0;
  /// What the bin stands on, and a table top's finish.
  enum class Floor { kNone, kTable, kConveyor };
  enum class Finish { kPainted, kMetal, kWood };
  Floor floor = Floor::kNone;
  Finish floor_finish = Finish::kPainted;
  Eigen::Vector3f floor_color{0, 0, 0};
  float floor_metallic = 0;
  float floor_roughness = 0;
  float floor_detail_strength = 0;
};

/// Draws a scene's surroundings: always 24 values of `engine`, whatever the settings, so that a
/// change of one probability moves none of the other draws (the table's finish and the tote's
/// saturation and value use only the last 8, so the first 16 mean the same whatever they say).
DrawnSurroundings SampleSurroundings(const config::SurroundingsConfig& config,
                                     std::mt19937_64& engine);

/// Display RGB of hue `hue_deg` (0..360), saturation and value (0..1).
Eigen::Vector3f RgbOfHsv(double hue_deg, double saturation, double value);

}  // namespace stackgen
