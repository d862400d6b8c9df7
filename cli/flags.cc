#include "cli/flags.h"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <utility>

#include "bus/bus.h"

namespace stackgen {
namespace {

// a number as the range shows it: "0", "1", "0.05", "86400", "inf"
std::string FormatBound(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

// text that strtoll/strtod would read past leading spaces: refused, as is the empty text
bool StartsBadly(const std::string& text) {
  return text.empty() || std::isspace(static_cast<unsigned char>(text[0])) != 0 || text[0] == '+';
}

}  // namespace

Interval Interval::All() {
  const double inf = std::numeric_limits<double>::infinity();
  return {-inf, inf, true, true};
}

bool Interval::Contains(double value) const {
  const bool above_min = min_open ? value > min : value >= min;
  const bool below_max = max_open ? value < max : value <= max;
  return std::isfinite(value) && above_min && below_max;
}

std::string Interval::ToString() const {
  if (std::isinf(min) && std::isinf(max)) return "";
  return (min_open ? "(" : "[") + FormatBound(min) + ", " + FormatBound(max) +
         (max_open ? ")" : "]");
}

int64_t ParseWholeNumber(const std::string& flag, const std::string& text, int64_t min,
                         int64_t max) {
  char* end = nullptr;
  errno = 0;
  const long long value = StartsBadly(text) ? 0 : std::strtoll(text.c_str(), &end, 10);
  if (StartsBadly(text) || *end != '\0' || errno != 0 || value < min || value > max) {
    throw UsageError(flag + " wants a whole number in " + std::to_string(min) + ".." +
                     std::to_string(max) + ", got \"" + text + "\"");
  }
  return value;
}

double ParseNumber(const std::string& flag, const std::string& text, const Interval& range) {
  char* end = nullptr;
  errno = 0;
  const double value = StartsBadly(text) ? 0 : std::strtod(text.c_str(), &end);
  if (StartsBadly(text) || *end != '\0' || errno != 0 || !range.Contains(value)) {
    const std::string in = range.ToString();
    throw UsageError(flag + " wants a number" + (in.empty() ? "" : " in " + in) + ", got \"" +
                     text + "\"");
  }
  return value;
}

double ParseDropFraction(const std::string& flag, const std::string& text) {
  try {
    return ParseNumber(flag, text, Interval::ClosedOpen(0, 1));
  } catch (const UsageError&) {
    throw std::invalid_argument(flag + " wants a fraction in [0, 1), got \"" + text + "\"");
  }
}

FlagParser::FlagParser(std::string program) : program_(std::move(program)) {}

FlagParser::Flag& FlagParser::Add(const std::string& name, bool takes_value,
                                  std::function<void(const std::string& value)> handle) {
  if (name.rfind("--", 0) != 0 || name.size() < 3 || name.find('=') != std::string::npos ||
      name == "--help") {
    throw std::logic_error("not a flag name: \"" + name + "\"");
  }
  Flag flag;
  flag.takes_value = takes_value;
  flag.handle = std::move(handle);
  if (!flags_.emplace(name, std::move(flag)).second) {
    throw std::logic_error("flag " + name + " registered twice");
  }
  return flags_.at(name);
}

void FlagParser::Int(const std::string& name, int64_t* out, int64_t min, int64_t max) {
  Add(name, true, [name, out, min, max](const std::string& value) {
    *out = ParseWholeNumber(name, value, min, max);
  });
}

void FlagParser::Int(const std::string& name, int* out, int min, int max) {
  Add(name, true, [name, out, min, max](const std::string& value) {
    *out = static_cast<int>(ParseWholeNumber(name, value, min, max));
  });
}

void FlagParser::Double(const std::string& name, double* out, const Interval& range) {
  Add(name, true,
      [name, out, range](const std::string& value) { *out = ParseNumber(name, value, range); });
}

void FlagParser::Double(const std::string& name, std::optional<double>* out,
                        const Interval& range) {
  Add(name, true,
      [name, out, range](const std::string& value) { *out = ParseNumber(name, value, range); });
}

void FlagParser::String(const std::string& name, std::string* out, const std::string& what) {
  Add(name, true, [name, out, what](const std::string& value) {
    if (value.empty() && !what.empty()) throw UsageError(name + " wants " + what + ", got \"\"");
    *out = value;
  });
}

void FlagParser::Custom(const std::string& name,
                        std::function<void(const std::string& value)> handle) {
  Add(name, true, std::move(handle));
}

void FlagParser::Switch(const std::string& name, bool* out) {
  Add(name, false, [out](const std::string&) { *out = true; });
}

void FlagParser::LcmUrl(std::string* out) {
  Add("--lcm-url", true, [out](const std::string& value) {
    if (value.empty()) throw UsageError("--lcm-url wants a URL (or \"default\"), got \"\"");
    *out = value == "default" ? "" : value;
  });
}

void FlagParser::BusKey(std::string* key_file, bool* open_bus) {
  Add("--bus-key-file", true, [key_file](const std::string& value) {
    if (value.empty()) throw UsageError("--bus-key-file wants a file, got \"\"");
    *key_file = value;
  });
  Switch("--open-bus", open_bus);
  Exclusive("--bus-key-file", "--open-bus");
}

void FlagParser::Replay(bool* out) { Switch("--replay", out); }

void FlagParser::Exclusive(const std::string& a, const std::string& b) {
  if (flags_.count(a) == 0 || flags_.count(b) == 0) {
    throw std::logic_error("Exclusive(" + a + ", " + b + "): no such flag");
  }
  exclusive_.emplace_back(a, b);
}

void FlagParser::FaultDrop(double* out) {
  Add("--fault-drop", true, [out](const std::string& value) {
    try {
      *out = ParseDropFraction("--fault-drop", value);
    } catch (const std::invalid_argument& error) {
      throw UsageError(error.what());
    }
  });
}

void FlagParser::Require(const std::string& name) {
  const auto found = flags_.find(name);
  if (found == flags_.end()) throw std::logic_error("Require(" + name + "): no such flag");
  found->second.required = true;
}

void FlagParser::Positional(std::vector<std::string>* out, const std::string& what, int min,
                            int max) {
  positional_ = out;
  positional_what_ = what;
  positional_min_ = min;
  positional_max_ = max;
}

void FlagParser::CheckGiven(int positional_count) const {
  if (positional_ != nullptr) {
    const std::string what = positional_what_;
    if (positional_count == 0 && positional_min_ > 0) throw UsageError("no " + what + " given");
    if (positional_count < positional_min_) {
      throw UsageError("at least " + std::to_string(positional_min_) + " " + what + "s, got " +
                       std::to_string(positional_count));
    }
    if (positional_count > positional_max_) {
      throw UsageError("at most " + std::to_string(positional_max_) + " " + what + "s, got " +
                       std::to_string(positional_count));
    }
  }
  for (const auto& [name, flag] : flags_) {
    if (flag.required && !flag.given) throw UsageError(name + " is required");
  }
  for (const auto& [a, b] : exclusive_) {
    if (flags_.at(a).given && flags_.at(b).given) {
      throw UsageError(a + " and " + b + " exclude each other");
    }
  }
}

bool FlagParser::Parse(int argc, const char* const* argv) {
  // every argument, in order; the first fault is kept and thrown at the end unless --help comes
  std::optional<UsageError> fault;
  const auto note = [&fault](const UsageError& error) {
    if (!fault) fault = error;
  };
  bool help = false;
  int positional_count = 0;
  for (auto& [name, flag] : flags_) flag.given = false;
  if (positional_ != nullptr) positional_->clear();
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    // --name=value or --name (value next)
    std::string name = arg;
    std::optional<std::string> value;
    const size_t equals = arg.find('=');
    if (arg.rfind("--", 0) == 0 && equals != std::string::npos) {
      name = arg.substr(0, equals);
      value = arg.substr(equals + 1);
    }
    if (name == "--help" || name == "-h") {
      if (value) {
        note(UsageError(name + " takes no value, got \"" + *value + "\""));
      } else {
        help = true;
      }
      continue;
    }

    // a positional argument, or an unknown one
    const bool looks_positional = arg[0] != '-' || arg == "-";
    const auto found = flags_.find(name);
    if (found == flags_.end()) {
      if (looks_positional && positional_ != nullptr) {
        ++positional_count;
        positional_->push_back(arg);
      } else {
        note(UsageError("unknown argument \"" + arg + "\""));
      }
      continue;
    }

    // the value: after '=', else the next argument; a switch takes none
    Flag& flag = found->second;
    flag.given = true;
    if (!flag.takes_value && value) {
      note(UsageError(name + " takes no value, got \"" + *value + "\""));
      continue;
    }
    if (flag.takes_value && !value) {
      if (i + 1 >= argc) {
        note(UsageError(name + " wants a value"));
        continue;
      }
      value = argv[++i];
    }
    try {
      flag.handle(value.value_or(""));
    } catch (const UsageError& error) {
      note(error);
    }
  }
  if (help) return false;
  if (fault) throw *fault;

  CheckGiven(positional_count);
  return true;
}

void FlagParser::ParseOrExit(int argc, char** argv, const std::function<void()>& help,
                             const std::function<void()>& check) {
  try {
    if (!Parse(argc, argv)) {
      help();
      std::fflush(stdout);
      std::exit(0);
    }
    if (check) check();
  } catch (const UsageError& error) {
    std::fprintf(stderr, "%s: error: %s (see --help)\n", program_.c_str(), error.what());
    std::exit(2);
  }
}

bool FlagParser::Given(const std::string& name) const {
  const auto found = flags_.find(name);
  return found != flags_.end() && found->second.given;
}

}  // namespace stackgen
