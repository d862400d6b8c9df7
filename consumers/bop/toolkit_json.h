#pragma once

// JSON as the BOP toolkit's inout.save_json writes it (Python's json.dumps with sort_keys, one
// entry per line at the top level), so a stackgen dataset is byte for byte what the toolkit
// writes for the same values.

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

namespace stackgen {

/// A finite double as Python's repr (and so the toolkit's json.dumps) writes it: the shortest
/// digits that read back the same, fixed notation for decimal exponents -4..15 ("0.1", "1.0",
/// "0.0001"), else "1e-05", "1.5e+16".
std::string PythonFloat(double value);

/// Writes a dict file whole (temporary name, then rename): "{\n", then '  "KEY": VALUE' per entry
/// in the given order (the caller sorts), ",\n" between them, "\n}".
void WriteToolkitFile(const std::filesystem::path& path,
                      const std::vector<std::pair<std::string, const nlohmann::json*>>& entries);

/// WriteToolkitFile of a JSON object with string keys (nlohmann keeps them sorted).
void WriteToolkitObject(const std::filesystem::path& path, const nlohmann::json& object);

/// What inout.save_json writes for `value`: a dict (keys in the order nlohmann holds them, or
/// numeric for `numeric_keys`) or a list one entry per line, anything else on one line.
std::string ToolkitText(const nlohmann::json& value, bool numeric_keys = false);

}  // namespace stackgen
