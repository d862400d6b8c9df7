// stackgen-forger: a stranger on the multicast group, for the trust tests
// (tests/e2e/trust_test.cc). It has no bus key (or another one: --bus-key-file) and attacks a
// running generator and writer the ways issue 14 lists, for --seconds:
// - forged scenes: every real scene it hears, sent again with another seed and no objects, under
//   its own seq and the next ones;
// - an impersonated writer: credits in the writer's name (its name heard on STACKGEN_STATUS) that
//   claim every scene stored, offer the largest window, or say it is leaving;
// - a window-0 credit under a name of its own, which would hold the generator;
// - a resend flood: requests in the writer's name for every seq published so far;
// - with --fuzz N: N messages of random bytes, and of real messages with bits flipped, cut or
//   grown, spread over every channel; with --signed-fuzz (and the right key) those on the
//   channels that cannot add a scene (status, config, labels, credits and resends addressed to
//   generator 999: its header rewritten) are signed, so they reach the decoders.
// Prints what it sent on stdout and exits 0. Not a test: a program the tests start.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <stackgen/config_text.hpp>
#include <stackgen/credit.hpp>
#include <stackgen/labels.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/flags.h"

namespace {

using Clock = std::chrono::steady_clock;

// SIGINT or SIGTERM ends the attack early (the summary is still printed)
volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

int Run(int argc, char** argv) {
  std::string lcm_url;
  std::string key_file;
  double seconds = 10;
  int64_t fuzz = 0;
  bool signed_fuzz = false;
  bool attacks = true;
  stackgen::FlagParser parser("stackgen-forger");
  parser.LcmUrl(&lcm_url);
  parser.BusKeyFile(&key_file);
  parser.Double("--seconds", &seconds, stackgen::Interval::OpenClosed(0, 3600));
  parser.Int("--fuzz", &fuzz, 0, 10000000);
  parser.Switch("--signed-fuzz", &signed_fuzz);
  bool no_attacks = false;
  parser.Switch("--no-attacks", &no_attacks);
  parser.ParseOrExit(argc, argv, [] {
    std::printf(
        "usage: stackgen-forger --lcm-url URL [--bus-key-file FILE] [--seconds S] [--fuzz N] "
        "[--signed-fuzz] [--no-attacks]\n");
  });
  attacks = !no_attacks;

  // a stranger: the suite's key ($STACKGEN_BUS_KEY_FILE) is not its own, only --bus-key-file;
  // what it sends unsigned goes out on a bus with no key
  // what it sends unsigned goes out on a bus with no key. It reads with no key either: a MAC
  // keeps no secret, so a stranger hears everything
  unsetenv("STACKGEN_BUS_KEY_FILE");
  stackgen::Bus stranger(stackgen::ResolveLcmUrl(lcm_url));
  stackgen::BusOptions options;
  options.key_file = key_file;
  std::unique_ptr<stackgen::Bus> keyed;
  if (!key_file.empty()) keyed = std::make_unique<stackgen::Bus>(stranger.url(), options);
  stackgen::Bus& bus = keyed ? *keyed : stranger;
  std::mt19937_64 random(20261125);

  // what it hears: the writer's name, real scenes and other messages to mutate
  std::string writer;
  int64_t highest_seq = -1;
  std::vector<std::pair<std::string, std::vector<uint8_t>>> samples;
  int64_t sent = 0, forged_scenes = 0;
  const auto keep_sample = [&](const std::string& channel, std::vector<uint8_t> bytes) {
    if (samples.size() < 64) {
      samples.emplace_back(channel, std::move(bytes));
    } else {
      samples[random() % samples.size()] = {channel, std::move(bytes)};
    }
  };
  // what does not decode (its own fuzz among it) is not its concern
  const std::function<void(const std::string&)> ignore = [](const std::string&) {};
  stranger.Subscribe<stackgen::status>(
      stackgen::kStatusChannel,
      [&](const stackgen::status& message) {
        if (message.process == "stackgen-coco") writer = message.name;
        keep_sample(stackgen::kStatusChannel, stackgen::EncodeMessage(message));
      },
      256, ignore);
  stranger.Subscribe<stackgen::credit>(
      stackgen::kCreditChannel,
      [&](const stackgen::credit& message) {
        keep_sample(stackgen::kCreditChannel, stackgen::EncodeMessage(message));
      },
      256, ignore);
  stranger.Subscribe<stackgen::config_text>(
      stackgen::kConfigChannel,
      [&](const stackgen::config_text& message) {
        keep_sample(stackgen::kConfigChannel, stackgen::EncodeMessage(message));
      },
      256, ignore);
  stranger.Subscribe<stackgen::scene>(
      stackgen::kSceneChannel,
      [&](const stackgen::scene& real) {
        // its own forgeries (and those of other strangers) come back: they have no objects
        if (real.instances.empty()) return;
        highest_seq = std::max(highest_seq, real.header.seq);
        if (!attacks) {
          if (samples.size() < 8)
            keep_sample(stackgen::kSceneChannel, stackgen::EncodeMessage(real));
          return;
        }
        // the forgery: another run's scene under the real ids, and the next seqs
        stackgen::scene forged = real;
        forged.header.seed = real.header.seed + 1;
        forged.instances.clear();
        forged.num_instances = 0;
        for (int64_t ahead = 0; ahead < 3; ++ahead) {
          forged.header.seq = real.header.seq + ahead;
          bus.Publish(stackgen::kSceneChannel, forged);
          ++forged_scenes;
          ++sent;
        }
        keep_sample(stackgen::kSceneChannel, stackgen::EncodeMessage(real));
      },
      256, ignore);

  const auto start = Clock::now();
  int64_t fuzzed = 0;
  const std::vector<std::string> channels = {stackgen::kSceneChannel,  stackgen::kLabelsChannel,
                                             stackgen::kStatusChannel, stackgen::kConfigChannel,
                                             stackgen::kCreditChannel, stackgen::kResendChannel};
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  while (!g_stop &&
         (Clock::now() - start < std::chrono::duration<double>(seconds) || fuzzed < fuzz)) {
    stranger.HandleFor(20);
    if (attacks && !writer.empty()) {
      // the writer impersonated: all stored, the largest window; then leaving
      stackgen::credit credit{};
      credit.header.generator_id = 0;
      credit.stored_through_seq = highest_seq + 100;
      credit.consumer = writer;
      credit.window = 10000;
      credit.last_received_seq = highest_seq + 100;
      bus.Publish(stackgen::kCreditChannel, credit);
      credit.leaving = true;
      bus.Publish(stackgen::kCreditChannel, credit);
      // a consumer of its own that offers no window
      credit = stackgen::credit{};
      credit.header.generator_id = 0;
      credit.stored_through_seq = -1;
      credit.consumer = "stackgen-coco@stranger:/nowhere";
      credit.window = 0;
      credit.last_received_seq = -1;
      bus.Publish(stackgen::kCreditChannel, credit);
      // the resend flood: everything published so far, in the writer's name
      stackgen::resend_request request{};
      request.header.generator_id = 0;
      request.consumer = writer;
      for (int64_t seq = 0; seq <= highest_seq && seq < 256; ++seq) request.seqs.push_back(seq);
      request.num_seqs = static_cast<int32_t>(request.seqs.size());
      bus.Publish(stackgen::kResendChannel, request);
      sent += 4;
    }
    // fuzz: spread over the run, a batch per round
    const double done =
        std::min(1.0, std::chrono::duration<double>(Clock::now() - start).count() / seconds * 1.25);
    while (fuzzed < fuzz && fuzzed < static_cast<int64_t>(done * static_cast<double>(fuzz))) {
      const std::string& channel = channels[static_cast<size_t>(fuzzed) % channels.size()];
      std::vector<uint8_t> bytes;
      const bool from_sample = !samples.empty() && random() % 4 != 0;
      if (from_sample) {
        bytes = samples[random() % samples.size()].second;
        switch (random() % 3) {
          case 0:  // bits flipped
            for (int flip = 0; flip < 1 + static_cast<int>(random() % 8); ++flip) {
              if (!bytes.empty()) bytes[random() % bytes.size()] ^= 1u << (random() % 8);
            }
            break;
          case 1:  // cut
            bytes.resize(random() % (bytes.size() + 1));
            break;
          default:  // grown
            bytes.resize(bytes.size() + 1 + random() % 4096, static_cast<uint8_t>(random()));
        }
      } else {
        bytes.resize(random() % 70000);
        for (uint8_t& byte : bytes) byte = static_cast<uint8_t>(random());
      }
      // signed only where no scene can come of it, and addressed to (or from) generator 999:
      // a signed message is a trusted process's word (a credit, a run, a generator's status)
      const bool harmless = channel != stackgen::kSceneChannel;
      if (signed_fuzz && harmless && bytes.size() >= 20) {
        bytes[16] = 0, bytes[17] = 0, bytes[18] = 0x03, bytes[19] = 0xE7;  // header.generator_id
      }
      if (signed_fuzz && harmless) {
        bus.PublishEncoded(channel, bytes);
      } else {
        stranger.PublishEncoded(channel, bytes);
      }
      ++fuzzed;
      ++sent;
    }
  }
  std::printf("stackgen-forger: sent %lld messages (%lld forged scenes, %lld fuzzed); writer %s\n",
              static_cast<long long>(sent), static_cast<long long>(forged_scenes),
              static_cast<long long>(fuzzed), writer.empty() ? "never heard" : writer.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen-forger: error: %s\n", error.what());
    return 1;
  }
}
