// FlagParser: the command line of every stackgen process, its value forms and its errors.

#include "cli/flags.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace stackgen {
namespace {

// argv for Parse: "prog" followed by `args`
class Argv {
 public:
  explicit Argv(std::vector<std::string> args) : strings_(std::move(args)) {
    strings_.insert(strings_.begin(), "prog");
    for (std::string& text : strings_) pointers_.push_back(text.data());
    pointers_.push_back(nullptr);
  }
  int argc() const { return static_cast<int>(strings_.size()); }
  char** argv() { return pointers_.data(); }

 private:
  std::vector<std::string> strings_;
  std::vector<char*> pointers_;
};

// the UsageError text Parse throws for `args`, or "" when it accepts them
std::string ErrorOf(FlagParser& parser, std::vector<std::string> args) {
  Argv argv(std::move(args));
  try {
    parser.Parse(argv.argc(), argv.argv());
  } catch (const UsageError& error) {
    return error.what();
  }
  return "";
}

// a parser with one flag of every kind, and where their values go
struct Fixture {
  int64_t count = 7;
  int columns = 4;
  double alpha = 0.05;
  std::optional<double> fraction;
  std::string out;
  std::string name;
  bool resume = false;
  std::vector<std::string> frames;
  FlagParser parser{"prog"};

  Fixture() {
    parser.Int("--count", &count, 0, INT64_MAX);
    parser.Int("--columns", &columns, 1, 100);
    parser.Double("--alpha", &alpha, Interval::Open(0, 1));
    parser.Double("--fraction", &fraction, Interval::Closed(0, 1));
    parser.String("--out", &out, "a folder");
    parser.String("--name", &name);
    parser.Switch("--resume", &resume);
    parser.Custom("--frame", [this](const std::string& value) { frames.push_back(value); });
  }
};

// `--name value` and `--name=value` set the same variables; flags not given keep their defaults.
TEST(FlagsTest, BothValueForms) {
  Fixture spaced;
  EXPECT_EQ(ErrorOf(spaced.parser, {"--count", "12", "--alpha", "0.5", "--out", "dir"}), "");
  Fixture equals;
  EXPECT_EQ(ErrorOf(equals.parser, {"--count=12", "--alpha=0.5", "--out=dir", "--name="}), "");
  for (const Fixture* fixture : {&spaced, &equals}) {
    EXPECT_EQ(fixture->count, 12);
    EXPECT_DOUBLE_EQ(fixture->alpha, 0.5);
    EXPECT_EQ(fixture->out, "dir");
    EXPECT_EQ(fixture->columns, 4);
    EXPECT_FALSE(fixture->fraction.has_value());
    EXPECT_FALSE(fixture->resume);
  }
  // only the first '=' splits; a value may start with '-' or hold '='
  Fixture tricky;
  EXPECT_EQ(ErrorOf(tricky.parser, {"--name=a=b", "--out", "-x"}), "");
  EXPECT_EQ(tricky.name, "a=b");
  EXPECT_EQ(tricky.out, "-x");
}

// an unknown flag, a stray word and "--" are refused, quoted as given.
TEST(FlagsTest, UnknownArgument) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--bogus"}), "unknown argument \"--bogus\"");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--bogus=3"}), "unknown argument \"--bogus=3\"");
  EXPECT_EQ(ErrorOf(fixture.parser, {"word"}), "unknown argument \"word\"");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--"}), "unknown argument \"--\"");
  EXPECT_EQ(ErrorOf(fixture.parser, {"-c", "3"}), "unknown argument \"-c\"");
}

// a value flag last on the line wants a value.
TEST(FlagsTest, MissingValue) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--out", "dir", "--count"}), "--count wants a value");
}

// whole numbers: the range is inclusive, and anything but a plain integer is refused naming the
// flag, the range and the text.
TEST(FlagsTest, IntRange) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--columns", "1"}), "");
  EXPECT_EQ(fixture.columns, 1);
  EXPECT_EQ(ErrorOf(fixture.parser, {"--columns", "100"}), "");
  EXPECT_EQ(fixture.columns, 100);
  EXPECT_EQ(ErrorOf(fixture.parser, {"--count", "9223372036854775807"}), "");
  EXPECT_EQ(fixture.count, INT64_MAX);
  for (const char* bad : {"0", "101", "x", "12x", "", " 5", "+5", "1.0", "99999999999999999999"}) {
    EXPECT_EQ(ErrorOf(fixture.parser, {"--columns", bad}),
              "--columns wants a whole number in 1..100, got \"" + std::string(bad) + "\"");
  }
  EXPECT_EQ(ErrorOf(fixture.parser, {"--count", "-3"}),
            "--count wants a whole number in 0..9223372036854775807, got \"-3\"");
}

// numbers: closed ends are included, open ends excluded, and non-finite or partial numbers are
// refused naming the flag, the interval and the text.
TEST(FlagsTest, DoubleRanges) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--fraction", "0", "--alpha", "1e-3"}), "");
  EXPECT_EQ(fixture.fraction, 0.0);
  EXPECT_DOUBLE_EQ(fixture.alpha, 0.001);
  EXPECT_EQ(ErrorOf(fixture.parser, {"--fraction", "1"}), "");
  EXPECT_EQ(fixture.fraction, 1.0);
  for (const char* bad : {"0", "1", "-0.5", "x", "0.5x", "", "nan", "inf"}) {
    EXPECT_EQ(ErrorOf(fixture.parser, {"--alpha", bad}),
              "--alpha wants a number in (0, 1), got \"" + std::string(bad) + "\"");
  }
  EXPECT_EQ(ErrorOf(fixture.parser, {"--fraction", "1.5"}),
            "--fraction wants a number in [0, 1], got \"1.5\"");
  EXPECT_EQ(Interval::ClosedOpen(0, 1).ToString(), "[0, 1)");
  EXPECT_EQ(Interval::OpenClosed(0, 86400).ToString(), "(0, 86400]");
  EXPECT_TRUE(Interval::All().Contains(-1e300));
  EXPECT_FALSE(Interval::All().Contains(std::numeric_limits<double>::infinity()));
  try {
    ParseNumber("--frame a", "x", Interval::All());
    ADD_FAILURE() << "accepted x";
  } catch (const UsageError& error) {
    EXPECT_STREQ(error.what(), "--frame a wants a number, got \"x\"");
  }
}

// a switch is set by its bare name and refuses a value after '='.
TEST(FlagsTest, SwitchGivenValue) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--resume"}), "");
  EXPECT_TRUE(fixture.resume);
  EXPECT_EQ(ErrorOf(fixture.parser, {"--resume=yes"}), "--resume takes no value, got \"yes\"");
  // a switch does not take the next argument as its value
  EXPECT_EQ(ErrorOf(fixture.parser, {"--resume", "word"}), "unknown argument \"word\"");
}

// a required flag that is not given is named; a String with `what` refuses the empty text.
TEST(FlagsTest, RequiredAndNonEmpty) {
  Fixture fixture;
  fixture.parser.Require("--out");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--count", "3"}), "--out is required");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--out", ""}), "--out wants a folder, got \"\"");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--out", "dir"}), "");
  EXPECT_TRUE(fixture.parser.Given("--out"));
  EXPECT_FALSE(fixture.parser.Given("--count"));
}

// a flag given twice: the last value wins; a Custom handler sees every value in order.
TEST(FlagsTest, RepeatedFlagLastWins) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--count", "1", "--count=2", "--frame", "a=1", "--frame",
                                     "b=2", "--resume", "--resume"}),
            "");
  EXPECT_EQ(fixture.count, 2);
  EXPECT_EQ(fixture.frames, (std::vector<std::string>{"a=1", "b=2"}));
}

// the first fault on the line is the one reported.
TEST(FlagsTest, FirstFaultReported) {
  Fixture fixture;
  EXPECT_EQ(ErrorOf(fixture.parser, {"--columns", "0", "--bogus"}),
            "--columns wants a whole number in 1..100, got \"0\"");
}

// positional arguments ("-" is one) are counted against their range; without Positional they
// are unknown arguments.
TEST(FlagsTest, Positional) {
  std::vector<std::string> datasets;
  std::string out;
  FlagParser parser("prog");
  parser.Positional(&datasets, "dataset", 1, 2);
  parser.String("--out", &out);
  EXPECT_EQ(ErrorOf(parser, {"--out", "o"}), "no dataset given");
  EXPECT_EQ(ErrorOf(parser, {"a", "b", "c"}), "at most 2 datasets, got 3");
  // each Parse starts from an empty list
  EXPECT_EQ(ErrorOf(parser, {"a", "--out", "o", "-"}), "");
  EXPECT_EQ(datasets, (std::vector<std::string>{"a", "-"}));
  EXPECT_EQ(ErrorOf(parser, {"a", "-x"}), "unknown argument \"-x\"");
}

// --fault-drop and --lcm-url mean the same in every program: "default" is the default bus, an
// empty URL and a fraction outside [0, 1) (or with a sign or spaces) are refused.
TEST(FlagsTest, BusFlags) {
  double drop = 0;
  std::string url = "unchanged";
  FlagParser parser("prog");
  parser.FaultDrop(&drop);
  parser.LcmUrl(&url);
  EXPECT_EQ(ErrorOf(parser, {"--fault-drop", "0.25", "--lcm-url=udpm://239.1.2.3:7"}), "");
  EXPECT_DOUBLE_EQ(drop, 0.25);
  EXPECT_EQ(url, "udpm://239.1.2.3:7");
  EXPECT_EQ(ErrorOf(parser, {"--lcm-url", "default"}), "");
  EXPECT_EQ(url, "");
  EXPECT_EQ(ErrorOf(parser, {"--lcm-url="}), "--lcm-url wants a URL (or \"default\"), got \"\"");
  for (const char* bad : {"1", "+0.5", " 0.5", "-0.1"}) {
    EXPECT_EQ(ErrorOf(parser, {"--fault-drop", bad}),
              "--fault-drop wants a fraction in [0, 1), got \"" + std::string(bad) + "\"");
  }
}

// --help and -h anywhere a flag may stand win over errors; as a flag's value they are a value.
TEST(FlagsTest, Help) {
  Fixture fixture;
  Argv help({"--columns", "0", "--bogus", "--help"});
  EXPECT_FALSE(fixture.parser.Parse(help.argc(), help.argv()));
  Argv short_help({"-h"});
  EXPECT_FALSE(fixture.parser.Parse(short_help.argc(), short_help.argv()));
  Argv as_value({"--name", "--help"});
  EXPECT_TRUE(fixture.parser.Parse(as_value.argc(), as_value.argv()));
  EXPECT_EQ(fixture.name, "--help");
  EXPECT_EQ(ErrorOf(fixture.parser, {"--help=x"}), "--help takes no value, got \"x\"");
}

// registering a flag twice, or a malformed name, is a programming error.
TEST(FlagsTest, BadRegistration) {
  Fixture fixture;
  int other = 0;
  EXPECT_THROW(fixture.parser.Int("--columns", &other, 0, 1), std::logic_error);
  EXPECT_THROW(fixture.parser.Int("columns", &other, 0, 1), std::logic_error);
  EXPECT_THROW(fixture.parser.Require("--nope"), std::logic_error);
}

// ParseOrExit: --help prints the help and exits 0.
TEST(FlagsDeathTest, HelpExits0) {
  Fixture fixture;
  Argv argv({"--help"});
  EXPECT_EXIT(fixture.parser.ParseOrExit(argv.argc(), argv.argv(),
                                         [] { std::fprintf(stderr, "the help\n"); }),
              ::testing::ExitedWithCode(0), "the help");
}

// ParseOrExit: a usage error, from a flag or from the program's own check, is one line
// "<program>: error: <text> (see --help)" and exit 2.
TEST(FlagsDeathTest, UsageErrorExits2) {
  Fixture fixture;
  Argv bad({"--count", "x"});
  EXPECT_EXIT(fixture.parser.ParseOrExit(bad.argc(), bad.argv(), [] {}),
              ::testing::ExitedWithCode(2),
              "^prog: error: --count wants a whole number in 0\\.\\.9223372036854775807, got "
              "\"x\" \\(see --help\\)\n$");
  Argv good({"--count", "3"});
  EXPECT_EXIT(fixture.parser.ParseOrExit(
                  good.argc(), good.argv(), [] {}, [] { throw UsageError("give either A or B"); }),
              ::testing::ExitedWithCode(2), "^prog: error: give either A or B \\(see --help\\)\n$");
}

}  // namespace
}  // namespace stackgen
