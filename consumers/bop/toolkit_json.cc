#include "consumers/bop/toolkit_json.h"

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <cstdlib>

#include "consumers/dataset/files.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// `value` as Python's json.dumps(value, sort_keys=True) writes it, which is how the toolkit's
// inout.save_json writes every entry: ", " and ": " between items, keys sorted, non-ASCII
// escaped, doubles as repr writes them (nlohmann's objects are sorted by key already)
void AppendToolkitJson(const json& value, std::string* out) {
  if (value.is_object()) {
    out->push_back('{');
    bool first = true;
    for (const auto& [key, item] : value.items()) {
      if (!first) out->append(", ");
      first = false;
      out->append(json(key).dump(-1, ' ', true)).append(": ");
      AppendToolkitJson(item, out);
    }
    out->push_back('}');
  } else if (value.is_array()) {
    out->push_back('[');
    bool first = true;
    for (const json& item : value) {
      if (!first) out->append(", ");
      first = false;
      AppendToolkitJson(item, out);
    }
    out->push_back(']');
  } else if (value.is_number_float()) {
    out->append(PythonFloat(value.get<double>()));
  } else {
    out->append(value.dump(-1, ' ', true));
  }
}

}  // namespace

std::string PythonFloat(double value) {
  char buffer[64];
  const auto result =
      std::to_chars(buffer, buffer + sizeof(buffer), value, std::chars_format::scientific);
  const std::string text(buffer, result.ptr);
  // "-d.ddde-XX": the sign, the digits and the exponent
  const size_t e = text.find('e');
  std::string mantissa = text.substr(0, e);
  const int exponent = std::stoi(text.substr(e + 1));
  const bool negative = mantissa[0] == '-';
  if (negative) mantissa.erase(0, 1);
  std::string digits = mantissa.substr(0, 1) + (mantissa.size() > 2 ? mantissa.substr(2) : "");
  std::string out = negative ? "-" : "";
  if (exponent < -4 || exponent >= 16) {
    out += digits.substr(0, 1);
    if (digits.size() > 1) out += "." + digits.substr(1);
    char exponent_text[16];
    std::snprintf(exponent_text, sizeof(exponent_text), "e%c%02d", exponent < 0 ? '-' : '+',
                  std::abs(exponent));
    return out + exponent_text;
  }
  if (exponent < 0)
    return out + "0." + std::string(static_cast<size_t>(-exponent - 1), '0') + digits;
  const size_t whole = static_cast<size_t>(exponent) + 1;
  if (digits.size() <= whole) return out + digits + std::string(whole - digits.size(), '0') + ".0";
  return out + digits.substr(0, whole) + "." + digits.substr(whole);
}

// a file as inout.save_json writes a dict: "{\n", then '  "KEY": VALUE' per entry in key order
// (`entries` is in that order already), ",\n" between them, "\n}"
void WriteToolkitFile(const fs::path& path,
                      const std::vector<std::pair<std::string, const json*>>& entries) {
  WriteFileWhole(path, [&](OutputFile& out) {
    out.Write("{\n");
    std::string line;
    for (size_t i = 0; i < entries.size(); ++i) {
      line = "  " + json(entries[i].first).dump(-1, ' ', true) + ": ";
      AppendToolkitJson(*entries[i].second, &line);
      line += i + 1 < entries.size() ? ",\n" : "\n";
      out.Write(line);
    }
    out.Write("}");
  });
}

// what inout.save_json writes for `value`: a dict (keys in the order nlohmann holds them, or
// numeric for `numeric_keys`) or a list one entry per line, anything else on one line
std::string ToolkitText(const json& value, bool numeric_keys) {
  std::string text;
  if (value.is_object()) {
    std::vector<std::pair<std::string, const json*>> entries;
    for (const auto& [key, item] : value.items()) entries.emplace_back(key, &item);
    if (numeric_keys) {
      std::stable_sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) {
        return std::stoll(a.first) < std::stoll(b.first);
      });
    }
    text = "{\n";
    for (size_t i = 0; i < entries.size(); ++i) {
      text += "  " + json(entries[i].first).dump(-1, ' ', true) + ": ";
      AppendToolkitJson(*entries[i].second, &text);
      text += i + 1 < entries.size() ? ",\n" : "\n";
    }
    return text + "}";
  }
  if (value.is_array()) {
    text = "[\n";
    for (size_t i = 0; i < value.size(); ++i) {
      text += "  ";
      AppendToolkitJson(value[i], &text);
      text += i + 1 < value.size() ? ",\n" : "\n";
    }
    return text + "]";
  }
  AppendToolkitJson(value, &text);
  return text;
}

// a JSON object with string keys, as WriteToolkitFile takes it
void WriteToolkitObject(const fs::path& path, const json& object) {
  std::vector<std::pair<std::string, const json*>> entries;
  for (const auto& [key, value] : object.items()) entries.emplace_back(key, &value);
  WriteToolkitFile(path, entries);
}

}  // namespace stackgen
