#include "gen/randomize/surroundings.h"

#include <cmath>

#include "gen/randomize/uniform.h"

namespace stackgen {

Eigen::Vector3f RgbOfHsv(double hue_deg, double saturation, double value) {
  // the hexcone model: the hue's sector, and where in it
  const double h = std::fmod(std::fmod(hue_deg, 360.0) + 360.0, 360.0) / 60.0;
  const double c = value * saturation;
  const double x = c * (1 - std::abs(std::fmod(h, 2.0) - 1));
  const double m = value - c;
  const int sector = static_cast<int>(h) % 6;
  const double rgb[6][3] = {{c, x, 0}, {x, c, 0}, {0, c, x}, {0, x, c}, {x, 0, c}, {c, 0, x}};
  return Eigen::Vector3f(static_cast<float>(rgb[sector][0] + m),
                         static_cast<float>(rgb[sector][1] + m),
                         static_cast<float>(rgb[sector][2] + m));
}

DrawnSurroundings SampleSurroundings(const config::SurroundingsConfig& config,
                                     std::mt19937_64& engine) {
  // twenty-four draws, in this order, whatever the settings
  double u[24];
  for (double& value : u) value = Uniform01(engine);
  DrawnSurroundings drawn;
  const auto between = [](double unit, double lo, double hi) { return lo + (hi - lo) * unit; };

  // the bin: bare steel, or a tote of another colour, or as configured
  if (u[0] < config.metal_bin_probability()) {
    drawn.bin_restyled = true;
    const float grey = static_cast<float>(between(u[2], 0.55, 0.8));
    drawn.bin_color = Eigen::Vector3f(grey, grey, grey * 1.02f).cwiseMin(1.f);
    drawn.bin_metallic = 1;
    drawn.bin_roughness = static_cast<float>(between(u[3], 0.2, 0.6));
  } else if (u[1] < config.bin_color_probability()) {
    drawn.bin_restyled = true;
    drawn.bin_color = RgbOfHsv(between(u[4], 0, 360),
                               between(u[5], config.bin_saturation_min(), config.bin_saturation_max()),
                               between(u[6], config.bin_value_min(), config.bin_value_max()));
    drawn.bin_metallic = 0;
    drawn.bin_roughness =
        static_cast<float>(between(u[3], config.bin_roughness_min(), config.bin_roughness_max()));
  }
  drawn.bin_scuffed = u[7] < config.scuffed_bin_probability();
  drawn.bin_scuff_strength = drawn.bin_scuffed ? static_cast<float>(between(u[8], 0.2, 0.8)) : 0;

  // the floor: a conveyor belt of dark rubber, or a table
  if (u[9] < config.table_probability()) {
    if (u[10] < config.conveyor_fraction()) {
      drawn.floor = DrawnSurroundings::Floor::kConveyor;
      const float grey = static_cast<float>(between(u[11], 0.04, 0.15));
      drawn.floor_color = Eigen::Vector3f(grey, grey, grey);
      drawn.floor_roughness = static_cast<float>(between(u[12], 0.5, 0.9));
      drawn.floor_detail_strength = static_cast<float>(between(u[13], 0.3, 0.8));
    } else {
      drawn.floor = DrawnSurroundings::Floor::kTable;
      drawn.floor_roughness = static_cast<float>(between(u[12], 0.3, 0.9));
      drawn.floor_detail_strength = static_cast<float>(between(u[13], 0.2, 0.7));
      if (u[16] < config.metal_table_fraction()) {
        // brushed steel
        drawn.floor_finish = DrawnSurroundings::Finish::kMetal;
        const float grey = static_cast<float>(between(u[22], 0.45, 0.8));
        drawn.floor_color = Eigen::Vector3f(grey, grey, grey);
        drawn.floor_metallic = 1;
        drawn.floor_roughness = static_cast<float>(between(u[23], 0.2, 0.5));
      } else if (u[16] < config.metal_table_fraction() + config.wood_table_fraction()) {
        // wood: a brown, its rings and grain from the detail
        drawn.floor_finish = DrawnSurroundings::Finish::kWood;
        drawn.floor_color =
            RgbOfHsv(between(u[19], 20, 40), between(u[20], 0.3, 0.65), between(u[21], 0.3, 0.85));
        drawn.floor_detail_strength = static_cast<float>(between(u[13], 0.5, 1.0));
      } else {
        // painted: a grey (saturation 0, the default) or a colour, a little warm or cold
        const Eigen::Vector3f paint =
            RgbOfHsv(between(u[17], 0, 360), between(u[18], 0, config.table_saturation_max()),
                     between(u[11], config.table_value_min(), config.table_value_max()));
        const float tint = static_cast<float>(between(u[14], -0.05, 0.05));
        drawn.floor_color =
            Eigen::Vector3f(paint.x() * (1 + tint), paint.y(), paint.z() * (1 - tint)).cwiseMin(1.f);
      }
    }
  }
  return drawn;
}

}  // namespace stackgen
