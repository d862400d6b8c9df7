// Test helpers for the physics: settle rules.

#pragma once

#include "gen/physics/pile.h"

namespace stackgen {
namespace testing {

/// The landed rule (1 mm, 1 degree over 0.25 s: when a falling pile counts as landed) as the
/// settle rule; the default publishes piles at rest (0.1 mm, 0.1 degree over 2 s): less physics,
/// for tests that do not depend on rest, and for comparing the two rules.
inline SimulationParams LandedRule() {
  SimulationParams params;
  params.settle_translation_mm = 1;
  params.settle_rotation_deg = 1;
  params.settle_window_s = 0.25;
  return params;
}

}  // namespace testing
}  // namespace stackgen
