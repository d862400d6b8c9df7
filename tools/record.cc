// stackgen-record: records channels of a udpm:// bus into a standard LCM log (what lcm-logger
// writes, lcm-logplayer plays and every stackgen consumer reads as file://), receiving through
// stackgen's own receiver (bus/udpm.h) rather than liblcm's, so the datagrams that make liblcm
// 1.3.1 write past a buffer (lcm-proj/lcm#628) cannot kill a recording. Messages are written as
// they came, bus-key trailers included and unchecked (as lcm-logger does): the log is read back
// with the key it was recorded under. tools/record runs it.

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <regex>
#include <stdexcept>
#include <string>

#include "bus/auth.h"
#include "bus/log.h"
#include "bus/udpm.h"
#include "cli/flags.h"

namespace stackgen {
namespace {

constexpr const char* kUsage =
    "Usage: stackgen-record --lcm-url URL --out FILE [--channels REGEX]\n"
    "\n"
    "Records the channels of a udpm:// bus that REGEX matches (whole names, ECMAScript\n"
    "syntax; default STACKGEN_(SCENE|LABELS|CONFIG|STATUS|MODEL)) into the LCM log FILE until\n"
    "SIGINT or SIGTERM, written as FILE.part and renamed into place at the end. FILE must not\n"
    "exist.\n"
    "Messages are kept as they came (their bus-key trailers unchecked), at most 1000 waiting per\n"
    "channel and 256 channels; the receiver's bounds are stackgen's (bus/udpm.h). tools/record\n"
    "is the way to run it.\n";

// how many messages of one channel may wait for the disk
constexpr int kQueueCapacity = 1000;

std::atomic<bool> stop_requested{false};
void RequestStop(int) { stop_requested = true; }

int Run(int argc, char** argv) {
  std::string url;
  std::string out;
  std::string channels = "STACKGEN_(SCENE|LABELS|CONFIG|STATUS|MODEL)";
  FlagParser parser("stackgen-record");
  parser.String("--lcm-url", &url, "a udpm:// URL");
  parser.Require("--lcm-url");
  parser.String("--out", &out, "a file");
  parser.Require("--out");
  parser.String("--channels", &channels, "a regular expression");
  // everything that can be checked before a file is made
  std::regex pattern;
  UdpmAddress address;
  parser.ParseOrExit(argc, argv, [] { std::printf("%s", kUsage); }, [&] {
    try {
      pattern = std::regex(channels, std::regex::ECMAScript);
    } catch (const std::regex_error& error) {
      throw UsageError("--channels '" + channels + "' is not a regular expression (" +
                       error.what() + ")");
    }
    try {
      address = ParseUdpmUrl(url);
    } catch (const std::runtime_error& error) {
      throw UsageError(std::string("--lcm-url: ") + error.what());
    }
  });
  if (std::filesystem::exists(out)) {
    throw std::runtime_error(out + " exists; pass another --out or remove it");
  }
  const std::string part = out + ".part";
  UdpmReceiver receiver(address, UdpmLimits{}, nullptr, "stackgen-record");
  receiver.SubscribeMatching(
      [pattern](const std::string& channel) { return std::regex_match(channel, pattern); },
      kQueueCapacity);

  std::signal(SIGINT, RequestStop);
  std::signal(SIGTERM, RequestStop);
  int64_t events = 0;
  uint64_t bytes = 0;
  {
    LogWriter log(part);
    std::printf("stackgen-record: recording %s on %s into %s\n", channels.c_str(), url.c_str(),
                out.c_str());
    std::fflush(stdout);
    UdpmMessage message;
    const auto write = [&] {
      log.WriteBytes(message.channel, message.data.get(), message.size, UnixMicros());
      ++events;
      bytes += message.size;
    };
    while (!stop_requested) {
      if (receiver.Take(100, &message) != UdpmReceiver::Taken::kMessage) continue;
      write();
      // what else is waiting, then to the kernel: a reader of FILE.part sees whole events
      while (receiver.Take(0, &message) == UdpmReceiver::Taken::kMessage) write();
      log.Flush();
    }
    // what is already queued goes in too
    while (receiver.Take(0, &message) == UdpmReceiver::Taken::kMessage) write();
    log.Close();
  }
  std::filesystem::rename(part, out);
  std::printf("stackgen-record: wrote %lld events (%llu bytes of messages) to %s; %s\n",
              static_cast<long long>(events), static_cast<unsigned long long>(bytes), out.c_str(),
              ReceiveSummary(receiver.counters()).c_str());
  return 0;
}

}  // namespace
}  // namespace stackgen

int main(int argc, char** argv) {
  try {
    return stackgen::Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen-record: error: %s\n", error.what());
    return 1;
  }
}
