// stackgen-coco: writes the scenes published on STACKGEN_SCENE into a COCO instances dataset.

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <map>
#include <optional>
#include <string>

#include <stackgen/scene.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "consumers/coco/coco_writer.h"

namespace {

constexpr const char* kProgram = "stackgen-coco";
// scenes LCM keeps waiting for us while an image is written
constexpr int kQueueCapacity = 1000;
// decode errors and invalid scenes reported one by one; later ones are only counted
constexpr int kMaxReportedErrors = 10;

std::atomic<bool> stop_requested{false};

void RequestStop(int) { stop_requested = true; }

struct Flags {
  std::string out;
  int64_t count = 0;
  std::string lcm_url;
  std::optional<double> min_visib_fract;  // unset: follow the generator's labels
};

void PrintHelp() {
  std::printf(
      "Usage: %s --out DIR [--count N] [--lcm-url URL] [--min-visib-fract F]\n"
      "\n"
      "Writes every scene published on %s into a COCO instances dataset:\n"
      "DIR/annotations.json and DIR/images/<generator_id>_<seq:06>.png (.jpg for JPEG scenes).\n"
      "Stops after N scenes, or on SIGINT/SIGTERM, and always leaves a valid dataset of the\n"
      "scenes received. Scenes repeated (same generator_id and seq) are stored once; seq gaps are\n"
      "reported as lost.\n"
      "\n"
      "The generator's labels decide what is written: an instance it marks annotated becomes an\n"
      "annotation (iscrowd 0), one it marks ignored (its occlusion rule IGNORE) an ignore region\n"
      "(iscrowd 1), any other is dropped. Every annotation holds the visible mask (segmentation,\n"
      "area, bbox) and the full one (amodal_segmentation, px_count_all, amodal_bbox).\n"
      "\n"
      "Options:\n"
      "  --out DIR             dataset folder (required). Created if missing; refused if it\n"
      "                        already holds a non-empty annotations.json (never overwritten).\n"
      "  --count N             stop after N scenes are stored (default 0: run until SIGINT or\n"
      "                        SIGTERM).\n"
      "  --lcm-url URL         LCM URL to listen on (default: $STACKGEN_LCM_URL when set, else\n"
      "                        %s).\n"
      "  --min-visib-fract F   also drop annotated objects whose visible fraction (visib_fract)\n"
      "                        is below F, 0..1: a stricter filter than the generator's\n"
      "                        annotation.min_visib_fract; it never adds objects the generator\n"
      "                        did not annotate and leaves ignore regions alone (default: none,\n"
      "                        follow the generator).\n"
      "  --help                print this help and exit.\n"
      "\n"
      "Exit status: 0 done, 1 error, 2 bad command line.\n",
      kProgram, stackgen::kSceneChannel, stackgen::kDefaultLcmUrl);
}

[[noreturn]] void UsageError(const std::string& text) {
  std::fprintf(stderr, "%s: error: %s (see --help)\n", kProgram, text.c_str());
  std::exit(2);
}

// a whole-string integer >= 0
int64_t ParseCount(const std::string& text) {
  size_t used = 0;
  long long value = -1;
  try {
    value = std::stoll(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || text.empty() || value < 0) {
    UsageError("--count wants a whole number >= 0, got \"" + text + "\"");
  }
  return value;
}

// a whole-string number in [0, 1]
double ParseFraction(const std::string& text) {
  size_t used = 0;
  double value = -1.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || text.empty() || !(value >= 0.0 && value <= 1.0)) {
    UsageError("--min-visib-fract wants a number in [0, 1], got \"" + text + "\"");
  }
  return value;
}

Flags ParseFlags(int argc, char** argv) {
  Flags flags;
  bool have_out = false;
  for (int i = 1; i < argc; ++i) {
    std::string name = argv[i];
    std::string value;
    bool have_value = false;
    // --name=value or --name value
    const size_t equals = name.find('=');
    if (name.rfind("--", 0) == 0 && equals != std::string::npos) {
      value = name.substr(equals + 1);
      name = name.substr(0, equals);
      have_value = true;
    }
    if (name == "--help" || name == "-h") {
      PrintHelp();
      std::exit(0);
    }
    if (name != "--out" && name != "--count" && name != "--lcm-url" &&
        name != "--min-visib-fract") {
      UsageError("unknown argument \"" + std::string(argv[i]) + "\"");
    }
    if (!have_value) {
      if (i + 1 >= argc) UsageError(name + " wants a value");
      value = argv[++i];
    }
    if (name == "--out") {
      if (value.empty()) UsageError("--out wants a folder");
      flags.out = value;
      have_out = true;
    } else if (name == "--count") {
      flags.count = ParseCount(value);
    } else if (name == "--lcm-url") {
      flags.lcm_url = value;
    } else {
      flags.min_visib_fract = ParseFraction(value);
    }
  }
  if (!have_out) UsageError("--out DIR is required");
  return flags;
}

// a fraction as %g prints it
std::string FormatFraction(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

std::string FormatDuration(double seconds) {
  const long total = static_cast<long>(seconds + 0.5);
  char text[32];
  std::snprintf(text, sizeof(text), "%ld:%02ld:%02ld", total / 3600, total / 60 % 60, total % 60);
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  try {
    // stop cleanly on SIGINT and SIGTERM: the handler only sets a flag
    struct sigaction action {};
    action.sa_handler = RequestStop;
    action.sa_flags = SA_RESTART;
    sigemptyset(&action.sa_mask);
    sigaction(SIGINT, &action, nullptr);
    sigaction(SIGTERM, &action, nullptr);

    // the dataset first, so a folder that holds one is refused before listening
    stackgen::CocoWriterOptions options;
    options.min_visib_fract = flags.min_visib_fract;
    stackgen::CocoWriter writer(flags.out, options);

    // counters of what did not make it into the dataset
    int64_t decode_errors = 0;
    int64_t invalid_scenes = 0;
    int64_t duplicates = 0;
    std::map<int32_t, int64_t> last_seq;  // per generator_id, the highest seq seen

    stackgen::Bus bus(stackgen::ResolveLcmUrl(flags.lcm_url));
    bus.Subscribe<stackgen::scene>(
        stackgen::kSceneChannel,
        [&](const stackgen::scene& scene) {
          // once --count scenes are stored, later ones in the same batch are left out
          if (flags.count > 0 && writer.num_images() >= flags.count) return;
          // report a seq gap as it appears
          const int32_t generator_id = scene.header.generator_id;
          const int64_t seq = scene.header.seq;
          const auto last = last_seq.find(generator_id);
          if (last != last_seq.end() && seq > last->second + 1) {
            std::fprintf(stderr, "%s: generator %d: lost seq %lld..%lld (%lld scenes)\n", kProgram,
                         generator_id, static_cast<long long>(last->second + 1),
                         static_cast<long long>(seq - 1),
                         static_cast<long long>(seq - 1 - last->second));
          }
          if (last == last_seq.end() || seq > last->second) last_seq[generator_id] = seq;
          // store it; an inconsistent scene is reported and skipped
          try {
            if (!writer.Add(scene)) ++duplicates;
          } catch (const stackgen::InvalidSceneError& error) {
            if (++invalid_scenes <= kMaxReportedErrors) {
              std::fprintf(stderr, "%s: skipped an invalid scene: %s\n", kProgram, error.what());
            }
          }
        },
        kQueueCapacity,
        [&](const std::string& text) {
          if (++decode_errors <= kMaxReportedErrors) {
            std::fprintf(stderr, "%s: skipped a message: %s\n", kProgram, text.c_str());
          }
        });

    std::printf("%s: listening on %s channel %s, writing %s\n", kProgram, bus.url().c_str(),
                stackgen::kSceneChannel, flags.out.c_str());
    std::fflush(stdout);

    // handle scenes until enough are stored or a signal arrives
    const bool show_progress = isatty(STDERR_FILENO) != 0;
    const auto start = std::chrono::steady_clock::now();
    auto last_progress = start;
    while (!stop_requested && (flags.count == 0 || writer.num_images() < flags.count)) {
      bus.HandleFor(100);
      const auto now = std::chrono::steady_clock::now();
      if (show_progress && now - last_progress >= std::chrono::milliseconds(500)) {
        last_progress = now;
        const double seconds = std::chrono::duration<double>(now - start).count();
        const double rate = writer.num_images() / std::max(seconds, 1e-9);
        std::string eta;
        if (flags.count > 0 && rate > 0) {
          eta = ", ETA " + FormatDuration((flags.count - writer.num_images()) / rate);
        }
        std::fprintf(stderr, "\r%s: %lld scenes, %.1f scenes/s%s   ", kProgram,
                     static_cast<long long>(writer.num_images()), rate, eta.c_str());
      }
    }
    if (show_progress) std::fprintf(stderr, "\n");

    // a valid dataset of what arrived
    writer.Finish();
    for (const auto& [generator_id, lost] : writer.LostPerGenerator()) {
      if (lost > 0) {
        std::fprintf(stderr, "%s: generator %d: %lld scenes lost\n", kProgram, generator_id,
                     static_cast<long long>(lost));
      }
    }
    if (decode_errors > 0 || invalid_scenes > 0 || duplicates > 0) {
      std::fprintf(stderr,
                   "%s: skipped %lld undecodable messages, %lld invalid scenes, %lld repeated "
                   "scenes\n",
                   kProgram, static_cast<long long>(decode_errors),
                   static_cast<long long>(invalid_scenes), static_cast<long long>(duplicates));
    }
    const std::string dropped_reason =
        flags.min_visib_fract
            ? "not annotated, or visib_fract < " + FormatFraction(*flags.min_visib_fract)
            : std::string("not annotated");
    std::printf(
        "%s: wrote %s/annotations.json: %lld images, %lld annotations, %lld ignore regions "
        "(iscrowd 1), %lld dropped (%s), %lld lost\n",
        kProgram, flags.out.c_str(), static_cast<long long>(writer.num_images()),
        static_cast<long long>(writer.num_annotations()),
        static_cast<long long>(writer.num_crowd()), static_cast<long long>(writer.num_dropped()),
        dropped_reason.c_str(), static_cast<long long>(writer.num_lost()));
    std::fflush(stdout);
    return 0;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
    return 1;
  }
}
