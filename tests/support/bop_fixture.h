#pragma once

// A BOP dataset for the tools' tests: stackgen-bop run on the recorded fixture log
// (tests/fixtures/logs/tiny.lcmlog: 4 scenes of 6 corner connectors, generator 2), so no
// generator and no renderer run. Tests using it depend on the stackgen-bop target.

#include <string>

#include "tests/support/process.h"

namespace stackgen::testing {

/// The fixture log the BOP dataset is made from.
inline const std::string kFixtureLog =
    std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog";

/// Writes the BOP dataset of the fixture log into `out` (a folder that does not exist yet) with
/// stackgen-bop; returns its exit code, and what it printed in `output`. The log was recorded
/// on an open bus (no key), so stackgen-bop reads it with --open-bus.
inline int MakeFixtureBop(const std::string& out, const std::string& log_prefix,
                          std::string* output) {
  std::string stdout_text, stderr_text;
  const int code =
      RunToEnd(std::string(STACKGEN_BIN_DIR) + "/stackgen-bop",
               {"--out", out, "--lcm-url", "file://" + kFixtureLog + "?speed=0", "--open-bus"},
               log_prefix, &stdout_text, &stderr_text, 120);
  *output = stdout_text + stderr_text;
  return code;
}

/// The chunk (BOP scene folder) of the fixture log's scenes in a dataset made by MakeFixtureBop:
/// generator 2, seqs 0..3.
inline std::string FixtureChunk(const std::string& out) { return out + "/train_pbr/2000000"; }

}  // namespace stackgen::testing
