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
// - with --lcm628: every round, on every channel, the two datagrams that make liblcm 1.3.1 write
//   about 4 GB past a buffer (a fragment offset that wraps a 32-bit sum, lcm-proj/lcm#628);
// - with --datagrams N: N raw datagrams in LCM's wire format (tests/support/lcm_wire.h) that no
//   LCM library sends: real messages (heard on the bus, and the events of --samples LOG), cut
//   into LC02 and LC03 datagrams, then mutated (bits flipped, header fields rewritten to wrapping
//   offsets, huge sizes and wrong counts, cut, grown, repeated, reordered, left out, sent from
//   four sockets at once), spread over --seconds, from a fixed seed;
// - with --fragment-flood N: N tiny datagrams spread over --seconds that would pin memory in
//   reassembly: 16 messages at a time from four sockets, on STACKGEN_LIVENESS (every keyed
//   process hears it) and STACKGEN_SCENE, each claiming 1 MiB in 8,192 fragments, begun by its
//   fragment 0 and fed one-byte fragments round robin, never completed;
// - with --claims N: N fragment-0 datagrams spread over --seconds, each claiming a 256 MiB
//   message on STACKGEN_SCENE (the eviction flood: in reassembly they would push real scenes out);
// - with --challenge-replay N: the liveness challenges it hears (signed by real processes),
//   played back N times in all over --seconds, each as it was recorded.
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
#include <thread>
#include <vector>

#include <stackgen/config_text.hpp>
#include <stackgen/credit.hpp>
#include <stackgen/labels.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/log.h"
#include "cli/flags.h"
#include "tests/support/lcm_wire.h"

namespace {

using Clock = std::chrono::steady_clock;

// SIGINT or SIGTERM ends the attack early (the summary is still printed)
volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

using Datagram = std::vector<uint8_t>;

// raw datagrams onto the group, from several sockets (senders), as a stranger writes them
class DatagramFuzzer {
 public:
  DatagramFuzzer(const std::string& url, uint64_t seed) : random_(seed) {
    for (int i = 0; i < 4; ++i) {
      senders_.push_back(std::make_unique<stackgen::testing::RawMulticastSender>(url));
    }
  }

  int64_t sent() const { return sent_; }

  // the two datagrams of lcm#628 on `channel`: fragment 0 of a 5000-byte message, then a
  // fragment at offset 0xFFFFFF00
  void Lcm628(const std::string& channel) {
    Datagram first = stackgen::testing::LcmFragmentHeader(seqno_, 5000, 0, 0, 2);
    first.insert(first.end(), channel.begin(), channel.end());
    first.push_back(0);
    first.resize(first.size() + 1000, 0);
    Datagram second = stackgen::testing::LcmFragmentHeader(seqno_, 5000, 0xFFFFFF00, 1, 2);
    second.resize(second.size() + 1000, 'A');
    ++seqno_;
    Send(0, first);
    Send(0, second);
  }

  // `bytes` on `channel` as datagrams, mutated one way, at most `budget` of them; returns how many
  // were sent
  int64_t Mutated(const std::string& channel, const std::vector<uint8_t>& bytes, int64_t budget) {
    const int64_t before = sent_;
    // LC02 when it fits and the coin says so, else LC03 fragments of liblcm's size or smaller
    std::vector<Datagram> datagrams;
    const size_t fragment =
        random_() % 3 == 0 ? stackgen::testing::kLcmFragmentPayload : 200 + random_() % 16000;
    if (channel.size() + 1 + bytes.size() <= stackgen::testing::kLcmShortMessageMax &&
        random_() % 3 == 0) {
      datagrams = stackgen::testing::LcmDatagrams(channel, bytes, seqno_);
    } else {
      datagrams = Fragments(channel, bytes, fragment);
    }
    ++seqno_;
    if (datagrams.empty()) return 0;
    Datagram& one = datagrams[random_() % datagrams.size()];
    int sender = static_cast<int>(random_() % senders_.size());
    switch (random_() % 10) {
      case 0:  // bits flipped
        for (int flip = 0; flip < 1 + static_cast<int>(random_() % 8); ++flip) {
          one[random_() % one.size()] ^= static_cast<uint8_t>(1u << (random_() % 8));
        }
        break;
      case 1: {  // a header field rewritten, often to a value that wraps or lies
        static const uint32_t kValues[] = {0,          1,          0xFFFFFFFF, 0xFFFFFF00,
                                           0x80000000, 0x10000000, 65487,      65535};
        const size_t at = 4 + 4 * (random_() % 4);
        const uint32_t value =
            random_() % 2 == 0 ? kValues[random_() % 8] : static_cast<uint32_t>(random_());
        for (int i = 0; i < 4 && at + i < one.size(); ++i) {
          one[at + i] = static_cast<uint8_t>(value >> (24 - 8 * i));
        }
        break;
      }
      case 2:  // cut
        one.resize(random_() % (one.size() + 1));
        break;
      case 3:  // grown
        one.resize(std::min<size_t>(65507, one.size() + 1 + random_() % 4096),
                   static_cast<uint8_t>(random_()));
        break;
      case 4:  // a fragment twice
        datagrams.push_back(one);
        break;
      case 5:  // out of order
        std::shuffle(datagrams.begin(), datagrams.end(), random_);
        break;
      case 6:  // one left out
        datagrams.erase(datagrams.begin() +
                        static_cast<std::ptrdiff_t>(random_() % datagrams.size()));
        break;
      case 7:  // a huge message claimed: 200 MB, or beyond any limit
        for (Datagram& datagram : datagrams) {
          if (datagram.size() < 20 || datagram[3] != '3') continue;
          const uint32_t huge = random_() % 2 == 0 ? 200u << 20 : 0xFFFFFFF0u;
          for (int i = 0; i < 4; ++i) datagram[8 + i] = static_cast<uint8_t>(huge >> (24 - 8 * i));
        }
        break;
      case 8:  // senders interleaved: each datagram from any socket
        sender = -1;
        break;
      default:  // as it was: a stranger's copy (refused by the bus key)
        break;
    }
    for (const Datagram& datagram : datagrams) {
      if (sent_ - before >= budget) break;
      if (!datagram.empty()) {
        Send(sender >= 0 ? sender : static_cast<int>(random_() % senders_.size()), datagram);
      }
    }
    return sent_ - before;
  }

  // datagram `index` of the fragment flood: 16 messages at a time, round robin (so that none
  // goes quiet), 4 from each socket (a sender's limit), 8 on STACKGEN_LIVENESS and 8 on
  // STACKGEN_SCENE; each claims 1 MiB in 8,192 fragments, its fragment 0 holds the channel and
  // one byte, the others one byte each, and the last is never sent
  void Flood(int64_t index) {
    constexpr uint32_t kSize = 1u << 20;
    constexpr uint16_t kCount = 8192;
    const int message = static_cast<int>(index % 16);
    const uint16_t number = static_cast<uint16_t>((index / 16) % (kCount - 1));
    const int64_t generation = index / (16 * (kCount - 1));
    const uint32_t seqno = 2000000 + 16 * static_cast<uint32_t>(generation) + message;
    const std::string channel =
        message < 8 ? stackgen::kLivenessChannel : stackgen::kSceneChannel;
    Datagram datagram = stackgen::testing::LcmFragmentHeader(
        seqno, kSize, number == 0 ? 0 : number * 128u, number, kCount);
    if (number == 0) {
      datagram.insert(datagram.end(), channel.begin(), channel.end());
      datagram.push_back(0);
    }
    datagram.push_back('F');
    Send(message % static_cast<int>(senders_.size()), datagram);
  }

  // fragment 0 of a message that claims 256 MiB on `channel`, under a seqno of its own
  void Claim(const std::string& channel) {
    Datagram datagram =
        stackgen::testing::LcmFragmentHeader(seqno_++, 256u << 20, 0, 0, 65535);
    datagram.insert(datagram.end(), channel.begin(), channel.end());
    datagram.push_back(0);
    datagram.resize(datagram.size() + 1000, 'C');
    Send(static_cast<int>(random_() % senders_.size()), datagram);
  }

 private:
  // LC03 fragments of `size` bytes (the first also holds the channel), whatever the message size
  std::vector<Datagram> Fragments(const std::string& channel, const std::vector<uint8_t>& bytes,
                                  size_t size) {
    std::vector<Datagram> datagrams;
    if (bytes.empty()) return datagrams;
    const size_t count =
        std::min<size_t>(65535, (channel.size() + 1 + bytes.size() + size - 1) / size);
    size_t offset = 0;
    for (size_t number = 0; number < count && offset < bytes.size(); ++number) {
      Datagram datagram = stackgen::testing::LcmFragmentHeader(
          seqno_, static_cast<uint32_t>(bytes.size()), static_cast<uint32_t>(offset),
          static_cast<uint16_t>(number), static_cast<uint16_t>(count));
      size_t room = size;
      if (number == 0) {
        datagram.insert(datagram.end(), channel.begin(), channel.end());
        datagram.push_back(0);
        room = room > channel.size() + 1 ? room - channel.size() - 1 : 1;
      }
      const size_t length = std::min(room, bytes.size() - offset);
      datagram.insert(datagram.end(), bytes.begin() + static_cast<std::ptrdiff_t>(offset),
                      bytes.begin() + static_cast<std::ptrdiff_t>(offset + length));
      offset += length;
      datagrams.push_back(std::move(datagram));
    }
    return datagrams;
  }

  void Send(int sender, const Datagram& datagram) {
    // a full send buffer: wait for it rather than lose the datagram (the count is the test's)
    for (int tries = 0; tries < 1000 && !senders_[sender]->Send(datagram); ++tries) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    ++sent_;
  }

  std::mt19937_64 random_;
  std::vector<std::unique_ptr<stackgen::testing::RawMulticastSender>> senders_;
  uint32_t seqno_ = 1000000;
  int64_t sent_ = 0;
};

int Run(int argc, char** argv) {
  std::string lcm_url;
  std::string key_file;
  double seconds = 10;
  int64_t fuzz = 0;
  bool signed_fuzz = false;
  bool attacks = true;
  stackgen::FlagParser parser("stackgen-forger");
  parser.LcmUrl(&lcm_url);
  parser.String("--bus-key-file", &key_file, "a file");
  parser.Double("--seconds", &seconds, stackgen::Interval::OpenClosed(0, 3600));
  parser.Int("--fuzz", &fuzz, 0, 10000000);
  parser.Switch("--signed-fuzz", &signed_fuzz);
  bool no_attacks = false;
  parser.Switch("--no-attacks", &no_attacks);
  bool lcm628 = false;
  parser.Switch("--lcm628", &lcm628);
  int64_t datagrams = 0;
  parser.Int("--datagrams", &datagrams, 0, 100000000);
  std::string samples_log;
  parser.String("--samples", &samples_log, "an LCM log");
  int64_t fragment_flood = 0, claims = 0, challenge_replay = 0;
  parser.Int("--fragment-flood", &fragment_flood, 0, 1000000000);
  parser.Int("--claims", &claims, 0, 1000000000);
  parser.Int("--challenge-replay", &challenge_replay, 0, 1000000000);
  parser.ParseOrExit(argc, argv, [] {
    std::printf(
        "usage: stackgen-forger --lcm-url URL [--bus-key-file FILE] [--seconds S] [--fuzz N] "
        "[--signed-fuzz] [--no-attacks] [--lcm628] [--datagrams N] [--samples LOG] "
        "[--fragment-flood N] [--claims N] [--challenge-replay N]\n");
  });
  attacks = !no_attacks;

  // a stranger: the suite's key ($STACKGEN_BUS_KEY_FILE) is not its own, only --bus-key-file.
  // What it sends unsigned goes out on an open bus, which it reads too: a MAC keeps no secret,
  // so a stranger hears everything. A keyed bus of its own answers the liveness checks by itself
  stackgen::BusOptions open;
  open.open_bus = true;
  stackgen::Bus stranger(stackgen::ResolveLcmUrl(lcm_url), open);
  stackgen::BusOptions options;
  options.key_file = key_file;
  std::unique_ptr<stackgen::Bus> keyed;
  if (!key_file.empty()) keyed = std::make_unique<stackgen::Bus>(stranger.url(), options);
  stackgen::Bus& bus = keyed ? *keyed : stranger;
  std::mt19937_64 random(20261125);
  DatagramFuzzer raw(stranger.url(), 20261126);
  // real messages to cut into datagrams: the events of a recorded log, then what it hears
  std::vector<std::pair<std::string, std::vector<uint8_t>>> datagram_samples;
  if (!samples_log.empty()) {
    stackgen::ReadLog(samples_log, [&](const stackgen::LogEvent& event) {
      datagram_samples.emplace_back(event.channel,
                                    std::vector<uint8_t>(event.data, event.data + event.size));
    });
  }

  // what it hears: the writer's name, real scenes and other messages to mutate
  std::string writer;
  int64_t highest_seq = -1;
  std::vector<std::pair<std::string, std::vector<uint8_t>>> samples;
  int64_t sent = 0, forged_scenes = 0;
  const auto keep_sample = [&](const std::string& channel, std::vector<uint8_t> bytes) {
    if (datagram_samples.size() < 64) {
      datagram_samples.emplace_back(channel, bytes);
    } else {
      datagram_samples[random() % datagram_samples.size()] = {channel, bytes};
    }
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

  // the liveness challenges heard, as they were sent (trailer and all): a receiver of its own
  std::vector<std::vector<uint8_t>> challenges;
  stackgen::UdpmReceiver recorder(stackgen::ParseUdpmUrl(stranger.url()), stackgen::UdpmLimits{},
                                  nullptr, "stackgen-forger");
  if (challenge_replay > 0) recorder.Subscribe(stackgen::kLivenessChannel, 64);

  const auto start = Clock::now();
  int64_t fuzzed = 0, flooded = 0, claimed = 0, replayed = 0;
  int64_t lcm628_pairs = 0;
  const std::vector<std::string> every_channel = {
      stackgen::kSceneChannel,  stackgen::kLabelsChannel, stackgen::kStatusChannel,
      stackgen::kConfigChannel, stackgen::kModelChannel,  stackgen::kCreditChannel,
      stackgen::kResendChannel};
  const std::vector<std::string> channels = {stackgen::kSceneChannel,  stackgen::kLabelsChannel,
                                             stackgen::kStatusChannel, stackgen::kConfigChannel,
                                             stackgen::kCreditChannel, stackgen::kResendChannel};
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  while (!g_stop && (Clock::now() - start < std::chrono::duration<double>(seconds) ||
                     fuzzed < fuzz || (raw.sent() < datagrams && !datagram_samples.empty()) ||
                     flooded < fragment_flood || claimed < claims ||
                     (replayed < challenge_replay && !challenges.empty()))) {
    stranger.HandleFor(fragment_flood > 0 || claims > 0 || challenge_replay > 0 ? 1 : 20);
    // the floods, spread over the run: what is due by now
    const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
    const double due = std::min(1.0, elapsed / seconds);
    for (; flooded < static_cast<int64_t>(due * static_cast<double>(fragment_flood)); ++flooded) {
      raw.Flood(flooded);
    }
    for (; claimed < static_cast<int64_t>(due * static_cast<double>(claims)); ++claimed) {
      raw.Claim(stackgen::kSceneChannel);
    }
    for (stackgen::UdpmMessage heard;
         recorder.Take(0, &heard) == stackgen::UdpmReceiver::Taken::kMessage;) {
      if (challenges.size() < 64) challenges.emplace_back(heard.data.get(), heard.data.get() + heard.size);
    }
    for (; !challenges.empty() &&
           replayed < static_cast<int64_t>(due * static_cast<double>(challenge_replay));
         ++replayed) {
      stranger.PublishEncoded(stackgen::kLivenessChannel,
                              challenges[static_cast<size_t>(replayed) % challenges.size()]);
    }
    if (lcm628) {
      for (const std::string& channel : every_channel) raw.Lcm628(channel);
      lcm628_pairs += static_cast<int64_t>(every_channel.size());
    }
    // raw datagrams, spread over the run like the fuzz below
    const double share =
        std::min(1.0, std::chrono::duration<double>(Clock::now() - start).count() / seconds * 1.25);
    while (!datagram_samples.empty() && raw.sent() < datagrams &&
           raw.sent() < static_cast<int64_t>(share * static_cast<double>(datagrams))) {
      const auto& [channel, bytes] = datagram_samples[random() % datagram_samples.size()];
      raw.Mutated(channel, bytes, datagrams - raw.sent());
    }
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
  std::printf(
      "stackgen-forger: sent %lld messages (%lld forged scenes, %lld fuzzed, %lld liveness "
      "messages replayed), %lld raw datagrams (%lld pairs of lcm#628, %lld of the fragment flood, "
      "%lld claims); writer %s\n",
      static_cast<long long>(sent), static_cast<long long>(forged_scenes),
      static_cast<long long>(fuzzed), static_cast<long long>(replayed),
      static_cast<long long>(raw.sent()), static_cast<long long>(lcm628_pairs),
      static_cast<long long>(flooded), static_cast<long long>(claimed),
      writer.empty() ? "never heard" : writer.c_str());
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
