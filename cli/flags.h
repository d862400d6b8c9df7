#pragma once

// The command-line layer of every stackgen process (stackgen, the consumers, the tools): one
// parser for their flags, so that every program reads `--name value` and `--name=value` alike and
// reports a bad command line in one line, `<program>: error: <text> (see --help)` on stderr, with
// exit status 2 (--help: exit status 0). It also hosts the bus flags every bus process shares,
// `--lcm-url URL`, `--bus-key-file PATH`, `--open-bus`, `--replay` and `--fault-drop F`, so they
// mean the same everywhere.
//
// The command line, as Parse reads it:
// - `--name value` or `--name=value` for a flag that takes a value; the value may start with '-'
//   (`--count -3` is a bad count, not a missing value). Only arguments that start with "--" are
//   split at their first '='.
// - `--name` alone for a switch; `--name=value` is an error.
// - a flag given twice: the last value wins (a Custom handler sees every value, in order).
// - `--help` or `-h` anywhere a flag may stand wins over every error on the command line.
// - an argument that does not start with '-' (or is "-" itself) is positional where the program
//   takes positional arguments (Positional), else an unknown argument.

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace stackgen {

/// A bad command line. what() is the text after "<program>: error: ", naming the flag and the
/// value at fault.
class UsageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// A range of numbers whose ends are each included (closed) or excluded (open); it prints as
/// "[0, 1)", "(0, 86400]", ...
struct Interval {
  double min = 0;
  double max = 0;
  bool min_open = false;
  bool max_open = false;

  /// [min, max], (min, max), [min, max), (min, max].
  static Interval Closed(double min, double max) { return {min, max, false, false}; }
  static Interval Open(double min, double max) { return {min, max, true, true}; }
  static Interval ClosedOpen(double min, double max) { return {min, max, false, true}; }
  static Interval OpenClosed(double min, double max) { return {min, max, true, false}; }
  /// Every finite number.
  static Interval All();

  bool Contains(double value) const;
  /// "[0, 1)"; empty for All().
  std::string ToString() const;
};

/// A whole-string integer in [min, max] (no sign '+', no spaces). Throws UsageError
/// `<flag> wants a whole number in MIN..MAX, got "<text>"`.
int64_t ParseWholeNumber(const std::string& flag, const std::string& text, int64_t min,
                         int64_t max);

/// A whole-string finite number in `range` (strtod's forms, no sign '+', no spaces). Throws
/// UsageError `<flag> wants a number in [0, 1), got "<text>"` (`<flag> wants a number, got ...`
/// for Interval::All()).
double ParseNumber(const std::string& flag, const std::string& text, const Interval& range);

/// Parses a --fault-drop value: a number in [0, 1). Throws std::invalid_argument naming `flag`.
double ParseDropFraction(const std::string& flag, const std::string& text);

/// The flags of one program: register each flag with where its value goes (its default is what
/// that variable holds before parsing), then Parse or ParseOrExit. Flag names include the
/// leading "--". Registering a name twice throws std::logic_error.
class FlagParser {
 public:
  /// `program` names the program in error lines ("stackgen-coco").
  explicit FlagParser(std::string program);

  /// --name N: a whole number in [min, max] (ParseWholeNumber and its error).
  void Int(const std::string& name, int64_t* out, int64_t min, int64_t max);
  void Int(const std::string& name, int* out, int min, int max);

  /// --name X: a finite number in `range` (ParseNumber and its error). The optional form is set
  /// only when the flag is given.
  void Double(const std::string& name, double* out, const Interval& range);
  void Double(const std::string& name, std::optional<double>* out, const Interval& range);

  /// --name TEXT: any text, the empty one included. With `what` given ("a folder") the text may
  /// not be empty: UsageError `<name> wants <what>, got ""`.
  void String(const std::string& name, std::string* out, const std::string& what = "");

  /// --name VALUE handed to `handle`, which may throw UsageError naming the flag and the value;
  /// called once per occurrence, in order (for flags given several times, like --frame).
  void Custom(const std::string& name, std::function<void(const std::string& value)> handle);

  /// --name with no value: sets *out to true. UsageError `<name> takes no value, got "<value>"`
  /// for --name=value.
  void Switch(const std::string& name, bool* out);

  /// --lcm-url URL, the bus to use; "default" (or leaving the flag out) sets "", which means
  /// ResolveLcmUrl's choice. An empty value is a usage error.
  void LcmUrl(std::string* out);

  /// --bus-key-file PATH, the bus key (auth.h); leaving it out means $STACKGEN_BUS_KEY_FILE when
  /// set, else this user's key (ResolveBusKeyFile). An empty value is a usage error. And
  /// --open-bus, no key at all (every sender trusted); the two exclude each other.
  void BusKey(std::string* key_file, bool* open_bus);

  /// --replay: the consumer reads a recording played back onto a live bus (lcm-logplayer), so
  /// messages are taken without the liveness check of the bus key (auth.h).
  void Replay(bool* out);

  /// Makes the flags `a` and `b` (registered before) exclude each other: Parse fails with
  /// UsageError `<a> and <b> exclude each other` when both are given.
  void Exclusive(const std::string& a, const std::string& b);

  /// --fault-drop F, the fraction of received messages the bus drops on purpose: a number in
  /// [0, 1) (ParseDropFraction and its error).
  void FaultDrop(double* out);

  /// Makes the flag `name` (registered before) mandatory: Parse fails with UsageError
  /// `<name> is required` when it is not given.
  void Require(const std::string& name);

  /// Takes positional arguments (see the file comment) into *out, min..max of them, called
  /// `what` in errors: UsageError `no <what> given` (none given, min > 0), `at least <min>
  /// <what>s, got <n>`, `at most <max> <what>s, got <n>`. Without this call a positional
  /// argument is an unknown argument.
  void Positional(std::vector<std::string>* out, const std::string& what, int min, int max);

  /// Reads argv[1..argc-1] into the registered variables. Returns false when --help or -h was
  /// given (the variables are then undefined), true otherwise. Throws UsageError on the first
  /// fault: `unknown argument "<arg>"`, `<name> wants a value` (a value flag last), a bad value,
  /// a switch given a value, a required flag missing, too few or too many positional arguments.
  bool Parse(int argc, const char* const* argv);

  /// Parse for main(): on --help or -h calls `help` (which prints the usage on stdout) and exits
  /// 0; then runs `check` when given (the program's rules between flags; it throws UsageError).
  /// On a UsageError prints `<program>: error: <text> (see --help)` on stderr and exits 2.
  void ParseOrExit(int argc, char** argv, const std::function<void()>& help,
                   const std::function<void()>& check = nullptr);

  /// True when the last Parse saw the flag `name` on the command line.
  bool Given(const std::string& name) const;

 private:
  // Throws UsageError unless what must be there is: positional arguments within their count (of
  // `positional_count` given), required flags, and no two flags that exclude each other.
  void CheckGiven(int positional_count) const;

  struct Flag {
    bool takes_value = true;
    bool required = false;
    bool given = false;
    std::function<void(const std::string& value)> handle;
  };
  Flag& Add(const std::string& name, bool takes_value,
            std::function<void(const std::string& value)> handle);

  std::string program_;
  std::map<std::string, Flag> flags_;
  std::vector<std::pair<std::string, std::string>> exclusive_;
  std::vector<std::string>* positional_ = nullptr;
  std::string positional_what_;
  int positional_min_ = 0;
  int positional_max_ = 0;
};

}  // namespace stackgen
