#pragma once

#include <cmath>
#include <cstdint>
#include <random>

#include <Eigen/Geometry>

namespace stackgen {

/// A double uniform in [0, 1) from exactly one value of `engine` (its top 53 bits). Used instead
/// of std::uniform_real_distribution, whose number of engine calls and results the standard
/// leaves to the library, so a draw takes the same values on every platform.
inline double Uniform01(std::mt19937_64& engine) {
  return static_cast<double>(engine() >> 11) * 0x1.0p-53;
}

/// A double uniform in [lo, hi] (exactly lo when lo == hi) from exactly one value of `engine`.
inline double Uniform(std::mt19937_64& engine, double lo, double hi) {
  return lo + (hi - lo) * Uniform01(engine);
}

/// A rotation uniform over SO(3) (Shoemake's method) from exactly three values of `engine`.
inline Eigen::Quaterniond UniformRotation(std::mt19937_64& engine) {
  const double u1 = Uniform01(engine);
  const double u2 = 2 * M_PI * Uniform01(engine);
  const double u3 = 2 * M_PI * Uniform01(engine);
  const double a = std::sqrt(1 - u1);
  const double b = std::sqrt(u1);
  return Eigen::Quaterniond(a * std::sin(u2), a * std::cos(u2), b * std::sin(u3), b * std::cos(u3))
      .normalized();
}

/// An index uniform in [0, n) from exactly one value of `engine`; n >= 1.
inline int UniformIndex(std::mt19937_64& engine, int n) {
  const auto index = static_cast<int>((static_cast<unsigned __int128>(engine()) * n) >> 64);
  return index;
}

}  // namespace stackgen
