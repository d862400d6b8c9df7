// stackgen-monitor: watches a run the way operators watch services. Listens to STACKGEN_STATUS
// and the scenes (a best-effort consumer: it sends no credits and never holds anyone back; its
// own status goes out like any consumer's) and serves, over HTTP on this host by default:
//   /metrics      the Prometheus text format: each generator's and consumer's counters
//   /status.json  the same for the page
//   /latest.jpg   the latest scenes as a contact sheet, their labels drawn
//   /             a live page: each process's state and rate, warnings for quiet ones, the sheet
//   /healthz      "ok" while it runs (a Kubernetes probe)
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <deque>
#include <mutex>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <stackgen/config_text.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "cli/flags.h"
#include "consumers/monitor/http_server.h"
#include "consumers/monitor/metrics.h"
#include "consumers/monitor/page.h"
#include "consumers/view/contact_sheet.h"
#include "contract/scene_contract.h"
#include "session/consumer.h"
#include "session/delivery.h"

namespace {

constexpr const char* kProgram = "stackgen-monitor";
constexpr int kDefaultPort = 9712;
// the latest scenes kept for the sheet, its columns and tile width, and how often it is drawn
// again at most (seconds)
constexpr size_t kLatestScenes = 6;
constexpr int kSheetColumns = 3;
constexpr int kTileWidth = 320;
constexpr double kSheetEveryS = 1.0;
// scenes the bus keeps waiting for the monitor (a best-effort consumer drops the rest)
constexpr int kQueueCapacity = 4;

struct Flags {
  std::vector<std::string> lcm_urls;  // every --lcm-url given, in order
  std::string bus_key_file;
  bool open_bus = false;
  bool replay = false;
  double fault_drop = 0;
  std::string bind = "127.0.0.1";
  int port = kDefaultPort;
};

void PrintHelp() {
  std::printf(
      "Usage: %s [--port N] [--bind ADDRESS] [--lcm-url URL ...] [--bus-key-file FILE | --open-bus]\n"
      "       [--replay] [--fault-drop F]\n"
      "\n"
      "Watches a run: listens to %s, the learners' progress and the scenes, and serves over\n"
      "HTTP\n"
      "  /metrics      every generator's and consumer's counters in the Prometheus text format\n"
      "                (scenes, redraws, resends, held-back seconds, stage seconds, lost,\n"
      "                refused messages by reason, seconds since last heard, quiet or not;\n"
      "                each learner's steps, loss, scenes taken and per second, reuse)\n"
      "  /status.json  the same for the page\n"
      "  /latest.jpg   the latest 6 scenes as a contact sheet, their labels drawn\n"
      "  /             a live page: each process's state and rate, quiet ones marked, and the\n"
      "                latest scenes\n"
      "  /healthz      ok while it runs\n"
      "A best-effort consumer: it never holds a generator back (no credits); its own counters go\n"
      "out on %s like any consumer's. Runs until SIGINT or SIGTERM.\n"
      "\n"
      "Options:\n"
      "  --port N            the port, 0..65535 (default %d; 0: one the system picks, printed)\n"
      "  --bind ADDRESS      the IPv4 address to listen on (default 127.0.0.1: this host only;\n"
      "                      0.0.0.0: every interface, e.g. in a container)\n"
      "  --lcm-url URL       the bus (default $STACKGEN_LCM_URL, else\n"
      "                      udpm://239.255.76.67:7667?ttl=0); given again, each bus too (a\n"
      "                      tools/task with a bus per generator): one table of them all\n"
      "  --bus-key-file FILE the bus key (default $STACKGEN_BUS_KEY_FILE, else this user's)\n"
      "  --open-bus          no key: check nothing\n"
      "  --replay            take a recording played onto the bus\n"
      "  --fault-drop F      drop the fraction F of what it receives (tests)\n"
      "  --help              print this help and exit\n"
      "\n"
      "Exit status: 0 stopped by a signal, 1 error, 2 bad command line.\n",
      kProgram, stackgen::kStatusChannel, stackgen::kStatusChannel, kDefaultPort);
}

volatile std::sig_atomic_t stop_requested = 0;
void RequestStop(int) { stop_requested = 1; }

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  parser.Int("--port", &flags.port, 0, 65535);
  parser.String("--bind", &flags.bind, "an IPv4 address");
  parser.Custom("--lcm-url", [&flags](const std::string& url) { flags.lcm_urls.push_back(url); });
  parser.BusKey(&flags.bus_key_file, &flags.open_bus);
  parser.Replay(&flags.replay);
  parser.FaultDrop(&flags.fault_drop);
  parser.ParseOrExit(argc, argv, PrintHelp);
  try {
    stackgen::StopOnSignals(RequestStop);
    // the table and the latest scenes, filled on this thread, read on the server's
    std::mutex mutex;
    stackgen::ProcessTable table;
    stackgen::MonitorCounters counters;
    std::deque<stackgen::scene> latest;
    std::vector<uchar> sheet_jpeg;
    double sheet_drawn_s = -1e9;
    bool sheet_stale = false;
    int64_t scenes_heard = 0;
    const stackgen::Clock& clock = stackgen::SteadyClock();
    const auto start = clock.Now();
    const auto now_s = [&] { return std::chrono::duration<double>(clock.Now() - start).count(); };

    // one consumer session per bus, all filling the one table
    if (flags.lcm_urls.empty()) flags.lcm_urls.push_back("");
    struct Watched {
      std::unique_ptr<stackgen::ConsumerSession> session;
      stackgen::Subscription statuses, learners, configs, scenes;
    };
    std::vector<Watched> watched;
    std::string urls;
    for (const std::string& url : flags.lcm_urls) {
      stackgen::ConsumerSessionOptions options;
      options.process = kProgram;
      options.name = std::string(kProgram) + "/" + std::to_string(getpid());
      Watched w;
      w.session = std::make_unique<stackgen::ConsumerSession>(
          std::make_unique<stackgen::Bus>(
              stackgen::ResolveLcmUrl(url),
              stackgen::ConsumerBusOptions(flags.fault_drop, flags.bus_key_file, flags.open_bus,
                                           flags.replay, 0x30)),
          options);
      stackgen::ConsumerSession& session = *w.session;
      urls += (urls.empty() ? "" : ", ") + session.bus().url();
      w.statuses = session.bus().Subscribe<stackgen::status>(
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
      // each generator's run, from its config (the writers' RunName), for the run label
      w.configs = session.bus().Subscribe<stackgen::config_text>(
          stackgen::kConfigChannel,
          [&](const stackgen::config_text& config) {
            const int32_t generator_id = config.header.generator_id;
            if (generator_id < 0 || generator_id > stackgen::kMaxGeneratorId ||
                config.header.seed < 0) {
              return;
            }
            const std::string run =
                stackgen::RunName(config.header.seed, config.path, config.pbtxt);
            const std::lock_guard<std::mutex> lock(mutex);
            table.SetRun(generator_id, run);
          },
          64,
          [&](const std::string&) {
            const std::lock_guard<std::mutex> lock(mutex);
            ++counters.bad_messages;
          });
      // learners' progress (stackgen.LearnerStatus, tools/train-live)
      w.learners = session.bus().Subscribe<stackgen::learner_status>(
          stackgen::kLearnerChannel,
          [&](const stackgen::learner_status& message) {
            const std::lock_guard<std::mutex> lock(mutex);
            table.UpdateLearner(message, now_s());
          },
          256,
          [&](const std::string&) {
            const std::lock_guard<std::mutex> lock(mutex);
            ++counters.bad_messages;
          });
      // the scenes: checked as every consumer checks them, the latest few kept for the sheet
      // (the session itself, not the loop's reference to it, is what the handler keeps)
      w.scenes = session.SubscribeScenes(
          stackgen::kSceneChannel,
          [&, own = &session](const stackgen::scene& message) {
            std::string why;
            if (!stackgen::CheckScene(message, &why)) {
              own->Refuse(message.header.generator_id, message.header.seq);
              return;
            }
            if (!own->Fresh(message.header.generator_id, message.header.seq)) return;
            const std::lock_guard<std::mutex> lock(mutex);
            latest.push_back(message);
            if (latest.size() > kLatestScenes) latest.pop_front();
            sheet_stale = true;
            ++scenes_heard;
          },
          kQueueCapacity,
          [&](const std::string&) {
            const std::lock_guard<std::mutex> lock(mutex);
            ++counters.bad_messages;
          });
      session.WatchGeneratorKeys();
      session.bus().state().WatchKeys({stackgen::kStatusChannel, stackgen::kLearnerChannel});
      watched.push_back(std::move(w));
    }
    // the sheet of the latest scenes, drawn again at most once a second (under `mutex`)
    const auto sheet = [&]() -> const std::vector<uchar>& {
      if (sheet_stale && now_s() - sheet_drawn_s >= kSheetEveryS) {
        std::vector<stackgen::sheet::Tile> tiles;
        for (auto it = latest.rbegin(); it != latest.rend(); ++it) {
          const stackgen::sheet::SceneView view = stackgen::sheet::ViewOfMessage(*it);
          tiles.push_back({stackgen::sheet::RenderTile(view, kTileWidth), view.caption});
        }
        const cv::Mat drawn = stackgen::sheet::ComposeSheet(tiles, kSheetColumns, kTileWidth,
                                                            false);
        cv::imencode(".jpg", drawn, sheet_jpeg, {cv::IMWRITE_JPEG_QUALITY, 85});
        sheet_drawn_s = now_s();
        sheet_stale = false;
      }
      return sheet_jpeg;
    };

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
      if (path == "/latest.jpg") {
        if (latest.empty()) return stackgen::HttpResponse{404, "text/plain", "no scene yet\n"};
        const std::vector<uchar>& jpeg = sheet();
        return stackgen::HttpResponse{200, "image/jpeg", std::string(jpeg.begin(), jpeg.end())};
      }
      if (path == "/") {
        return stackgen::HttpResponse{200, "text/html; charset=utf-8", stackgen::kMonitorPage};
      }
      return stackgen::HttpResponse{404, "text/plain", "not found: " + path + "\n"};
    });
    std::printf("%s: serving http://%s:%d/ (metrics at /metrics), listening on %s channels %s "
                "and %s\n",
                kProgram, flags.bind.c_str(), server.port(), urls.c_str(),
                stackgen::kStatusChannel, stackgen::kSceneChannel);
    std::fflush(stdout);

    const int slice_ms = std::max(10, 100 / static_cast<int>(watched.size()));
    while (!stop_requested) {
      stackgen::AuthCounters refused;
      for (Watched& w : watched) {
        w.session->bus().HandleFor(slice_ms);
        const stackgen::AuthCounters bus_refused = w.session->bus().state().auth_counters();
        refused.unsigned_messages += bus_refused.unsigned_messages;
        refused.forged += bus_refused.forged;
        refused.replayed += bus_refused.replayed;
        refused.relayed += bus_refused.relayed;
      }
      int64_t held = 0;
      {
        const std::lock_guard<std::mutex> lock(mutex);
        counters.refused_unsigned = refused.unsigned_messages;
        counters.refused_forged = refused.forged;
        counters.refused_replayed = refused.replayed;
        counters.refused_relayed = refused.relayed;
        held = scenes_heard;
      }
      for (Watched& w : watched) w.session->Service(held, held);
    }
    for (Watched& w : watched) w.session->Leave(scenes_heard, scenes_heard, stackgen::kRunStopped);
    std::printf("%s: stopped; heard %lld statuses of %zu processes\n", kProgram,
                static_cast<long long>(counters.status_messages), table.entries().size());
    return 0;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: error: %s\n", kProgram, error.what());
    return 1;
  }
}
