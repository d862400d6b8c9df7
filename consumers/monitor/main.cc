// stackgen-monitor: watches a run the way operators watch services. Listens to STACKGEN_STATUS
// (a best-effort listener: it sends nothing but the bus key's liveness answers and never holds
// anyone back) and serves, over HTTP on this host by default:
//   /metrics      the Prometheus text format: each generator's and consumer's counters
//   /status.json  the same for the page
//   /             a live page: each process's state and rate, warnings for quiet ones
//   /healthz      "ok" while it runs (a Kubernetes probe)
#include <csignal>
#include <cstdio>
#include <mutex>
#include <string>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "cli/flags.h"
#include "consumers/monitor/http_server.h"
#include "consumers/monitor/metrics.h"
#include "consumers/monitor/page.h"
#include "session/consumer.h"

namespace {

constexpr const char* kProgram = "stackgen-monitor";
constexpr int kDefaultPort = 9712;

struct Flags {
  std::string lcm_url;
  std::string bus_key_file;
  bool open_bus = false;
  bool replay = false;
  double fault_drop = 0;
  std::string bind = "127.0.0.1";
  int port = kDefaultPort;
};

void PrintHelp() {
  std::printf(
      "Usage: %s [--port N] [--bind ADDRESS] [--lcm-url URL] [--bus-key-file FILE | --open-bus]\n"
      "       [--replay] [--fault-drop F]\n"
      "\n"
      "Watches a run: listens to %s and serves over HTTP\n"
      "  /metrics      every generator's and consumer's counters in the Prometheus text format\n"
      "                (scenes, redraws, resends, held-back seconds, stage seconds, lost,\n"
      "                refused messages by reason, seconds since last heard, quiet or not)\n"
      "  /status.json  the same for the page\n"
      "  /             a live page: each process's state and rate, quiet ones marked\n"
      "  /healthz      ok while it runs\n"
      "It never holds a generator back (it takes no scenes and sends no credits). Runs until\n"
      "SIGINT or SIGTERM.\n"
      "\n"
      "Options:\n"
      "  --port N            the port, 0..65535 (default %d; 0: one the system picks, printed)\n"
      "  --bind ADDRESS      the IPv4 address to listen on (default 127.0.0.1: this host only;\n"
      "                      0.0.0.0: every interface, e.g. in a container)\n"
      "  --lcm-url URL       the bus (default $STACKGEN_LCM_URL, else udpm://239.255.76.67:7667?ttl=0)\n"
      "  --bus-key-file FILE the bus key (default $STACKGEN_BUS_KEY_FILE, else this user's)\n"
      "  --open-bus          no key: check nothing\n"
      "  --replay            take a recording played onto the bus\n"
      "  --fault-drop F      drop the fraction F of what it receives (tests)\n"
      "  --help              print this help and exit\n"
      "\n"
      "Exit status: 0 stopped by a signal, 1 error, 2 bad command line.\n",
      kProgram, stackgen::kStatusChannel, kDefaultPort);
}

volatile std::sig_atomic_t stop_requested = 0;
void RequestStop(int) { stop_requested = 1; }

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  parser.Int("--port", &flags.port, 0, 65535);
  parser.String("--bind", &flags.bind, "an IPv4 address");
  parser.LcmUrl(&flags.lcm_url);
  parser.BusKey(&flags.bus_key_file, &flags.open_bus);
  parser.Replay(&flags.replay);
  parser.FaultDrop(&flags.fault_drop);
  parser.ParseOrExit(argc, argv, PrintHelp);
  try {
    stackgen::StopOnSignals(RequestStop);
    stackgen::Bus bus(stackgen::ResolveLcmUrl(flags.lcm_url),
                      stackgen::ConsumerBusOptions(flags.fault_drop, flags.bus_key_file,
                                                   flags.open_bus, flags.replay, 0x30));
    // the table, filled on this thread, read on the server's
    std::mutex mutex;
    stackgen::ProcessTable table;
    stackgen::MonitorCounters counters;
    const stackgen::Clock& clock = stackgen::SteadyClock();
    const auto start = clock.Now();
    const auto now_s = [&] { return std::chrono::duration<double>(clock.Now() - start).count(); };
    const stackgen::Subscription statuses = bus.Subscribe<stackgen::status>(
        stackgen::kStatusChannel,
        [&](const stackgen::status& message) {
          const std::lock_guard<std::mutex> lock(mutex);
          table.Update(message, now_s());
          ++counters.status_messages;
        },
        1024,
        [&](const std::string&) {
          const std::lock_guard<std::mutex> lock(mutex);
          ++counters.bad_messages;
        });
    bus.state().WatchKeys({stackgen::kStatusChannel, stackgen::kConfigChannel});

    stackgen::HttpServer server(flags.bind, flags.port, [&](const std::string&,
                                                            const std::string& path) {
      const std::lock_guard<std::mutex> lock(mutex);
      if (path == "/metrics") {
        return stackgen::HttpResponse{200, "text/plain; version=0.0.4; charset=utf-8",
                                      stackgen::PrometheusText(table, counters, now_s())};
      }
      if (path == "/status.json") {
        return stackgen::HttpResponse{200, "application/json",
                                      stackgen::StatusJson(table, counters, now_s())};
      }
      if (path == "/healthz") return stackgen::HttpResponse{200, "text/plain", "ok\n"};
      if (path == "/") {
        return stackgen::HttpResponse{200, "text/html; charset=utf-8", stackgen::kMonitorPage};
      }
      return stackgen::HttpResponse{404, "text/plain", "not found: " + path + "\n"};
    });
    std::printf("%s: serving http://%s:%d/ (metrics at /metrics), listening on %s channel %s\n",
                kProgram, flags.bind.c_str(), server.port(), bus.url().c_str(),
                stackgen::kStatusChannel);
    std::fflush(stdout);

    while (!stop_requested) {
      bus.HandleFor(100);
      const stackgen::AuthCounters refused = bus.state().auth_counters();
      const std::lock_guard<std::mutex> lock(mutex);
      counters.refused_unsigned = refused.unsigned_messages;
      counters.refused_forged = refused.forged;
      counters.refused_replayed = refused.replayed;
      counters.refused_relayed = refused.relayed;
    }
    std::printf("%s: stopped; heard %lld statuses of %zu processes\n", kProgram,
                static_cast<long long>(counters.status_messages), table.entries().size());
    return 0;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
    return 1;
  }
}
