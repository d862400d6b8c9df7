#include "consumers/dataset/writer_main.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <set>

#include <nlohmann/json.hpp>
#include <stackgen/config_text.hpp>
#include <stackgen/status.hpp>

#include "bus/auth.h"
#include "bus/channels.h"
#include "bus/consumer.h"
#include "bus/delivery.h"
#include "bus/scene_contract.h"

namespace stackgen {
namespace {

// scenes LCM keeps waiting for us while a scene is written
constexpr int kQueueCapacity = 1000;
// generators heard for this long that all use another bus key stop the writer (seconds): they
// publish their config every second, so one with the right key would have been heard by then
constexpr double kKeyMismatchS = 2.0;
// decode errors and invalid scenes reported one by one; later ones are only counted
constexpr int kMaxReportedErrors = 10;

std::atomic<bool> stop_requested{false};

void RequestStop(int) { stop_requested = true; }

std::string FormatDuration(double seconds) {
  const long total = static_cast<long>(seconds + 0.5);
  char text[32];
  std::snprintf(text, sizeof(text), "%ld:%02ld:%02ld", total / 3600, total / 60 % 60, total % 60);
  return text;
}

// the consumer's name in credits: stable across restarts of a writer on the same folder
std::string ConsumerName(const std::string& program, const std::string& out) {
  char host[256] = "localhost";
  gethostname(host, sizeof(host) - 1);
  std::error_code error;
  const std::filesystem::path absolute = std::filesystem::absolute(out, error);
  return program + "@" + host + ":" + (error ? out : absolute.string());
}

// The output folder must be absent or empty, or (with --resume) hold this program's journal: a
// writer never writes into what is not its own dataset, and a dataset is resumed, not started
// again. Returns whether the folder is absent (the writer makes it). Throws one line naming it.
bool CheckOutputFolder(const WriterProgram& program, const WriterFlags& flags) {
  namespace fs = std::filesystem;
  std::error_code error;
  const fs::file_status status = fs::status(flags.out, error);
  if (!fs::exists(status)) return true;
  if (!fs::is_directory(status)) {
    throw std::runtime_error("--out " + flags.out + " is not a folder");
  }
  const fs::directory_iterator entries(flags.out, error);
  if (error)
    throw std::runtime_error("cannot read the folder " + flags.out + ": " + error.message());
  std::set<std::string> names;  // sorted: the error names the first few
  for (const fs::directory_entry& entry : entries) names.insert(entry.path().filename().string());
  const bool journal = names.count(program.journal) != 0;
  std::string first;
  for (const std::string& name : names) {
    if (first.size() > 60) {
      first += ", ...";
      break;
    }
    first += (first.empty() ? "" : ", ") + name;
  }
  if (first.empty()) return false;
  if (journal && !flags.resume) {
    throw std::runtime_error(flags.out + " holds a " + program.name + " dataset (" +
                             program.journal +
                             "): continue it with --resume, or choose an empty or new --out "
                             "folder");
  }
  // another writer's dataset is named as such: it is continued by its own program
  const std::pair<const char*, const char*> journals[] = {{"annotations.journal", "stackgen-coco"},
                                                          {"bop.journal", "stackgen-bop"}};
  for (const auto& [other_journal, other_program] : journals) {
    if (!journal && names.count(other_journal) != 0) {
      throw std::runtime_error(flags.out + " holds a " + other_program + " dataset (" +
                               other_journal + "), not a " + program.name + " one: " +
                               (flags.resume ? "resume it with " + std::string(other_program)
                                             : "write into an empty or new --out folder"));
    }
  }
  if (!journal) {
    throw std::runtime_error(flags.out + " is not empty (it holds " + first + ") and holds no " +
                             program.name + " dataset (no " + program.journal + "): " +
                             program.name + " writes only into an empty or new --out folder" +
                             (flags.resume ? ", or resumes its own dataset" : ""));
  }
  return false;
}

// removes what a writer that stored nothing made in `out` (it was empty when it started), and
// `out` itself when the writer made it
void RemoveDatasetFolder(const std::string& out, bool created_folder) {
  namespace fs = std::filesystem;
  std::error_code ignored;
  for (const fs::directory_entry& entry : fs::directory_iterator(out, ignored)) {
    fs::remove_all(entry.path(), ignored);
  }
  if (created_folder) fs::remove(out, ignored);
}

}  // namespace

bool IsUtf8(const std::string& text) {
  try {
    nlohmann::json(text).dump();
    return true;
  } catch (const nlohmann::json::type_error&) {
    return false;
  }
}

std::map<int32_t, int64_t> LostBetween(const std::map<int32_t, std::vector<int64_t>>& seqs) {
  std::map<int32_t, int64_t> lost;
  for (const auto& [generator_id, stored] : seqs) {
    if (stored.empty()) continue;
    lost[generator_id] = stored.back() - stored.front() + 1 - static_cast<int64_t>(stored.size());
  }
  return lost;
}

void AddWriterFlags(FlagParser* parser, WriterFlags* flags) {
  parser->String("--out", &flags->out, "a folder");
  parser->Require("--out");
  parser->Int("--count", &flags->count, 0, INT64_MAX);
  parser->Switch("--resume", &flags->resume);
  parser->LcmUrl(&flags->lcm_url);
  parser->BusKey(&flags->bus_key_file, &flags->open_bus);
  parser->Replay(&flags->replay);
  parser->Int("--window", &flags->window, 1, 10000);
  parser->Int("--group-commit", &flags->group_commit, 1, 10000);
  parser->FaultDrop(&flags->fault_drop);
  parser->Int("--warn-silent", &flags->warn_silent_s, 0, 86400);
}

std::string WriterFlagsHelp(const std::string& journal) {
  return std::string(
             "  --count N             stop after N scenes are stored (default 0: run until SIGINT "
             "or\n"
             "                        SIGTERM).\n"
             "  --resume              continue the dataset in DIR after a crash or a stop: "
             "reloads\n"
             "                        ") +
         journal +
         " (a torn last record is cut) and stores only\n"
         "                        scenes it does not hold; --count counts the scenes already "
         "there.\n"
         "  --lcm-url URL         LCM URL to listen on (default: $STACKGEN_LCM_URL when set, else\n"
         "                        " +
         kDefaultLcmUrl +
         ").\n"
         "  --bus-key-file FILE   the bus key shared with the generators: messages not signed "
         "with\n"
         "                        it are refused and counted, credits are signed (default:\n"
         "                        $STACKGEN_BUS_KEY_FILE, else this user's key\n"
         "                        ~/.config/stackgen/bus.key, made on first use).\n"
         "  --open-bus            no bus key: sign nothing, trust every sender on the group.\n"
         "  --replay              the scenes come from a recording played back onto the bus\n"
         "                        (lcm-logplayer): take them without the liveness check that\n"
         "                        refuses recordings by default (a file:// log needs no flag).\n"
         "  --window N            scenes a generator may run ahead of what is stored, 1..10000\n"
         "                        (default 8).\n"
         "  --warn-silent S       say so on stderr when no generator has been heard for S\n"
         "                        seconds (no scene, no config), naming the URL and the key to\n"
         "                        check; again after each new silence (default 10; 0: never).\n"
         "  --group-commit N      scenes made durable together, 1..10000 (default 16): scenes\n"
         "                        are written as they come and made durable (one sync of the file\n"
         "                        system, one of the journal) and credited once N are waiting or\n"
         "                        no more have arrived; 1: each scene on its own.\n"
         "  --fault-drop F        drop the fraction F in [0, 1) of the messages received, from a\n"
         "                        fixed seed: for tests and demos of lossless delivery (default "
         "0).\n";
}

int RunWriter(const WriterProgram& program, const WriterFlags& flags) {
  const char* const name_text = program.name.c_str();
  // a file too large for RLIMIT_FSIZE is a write error with a message, not a silent kill
  std::signal(SIGXFSZ, SIG_IGN);
  // declared here so that the error path below can still finish the dataset; the client
  // refers to the bus, so it goes first
  std::unique_ptr<DatasetSink> writer;
  std::unique_ptr<Bus> bus_owner;
  std::unique_ptr<SceneClient> client;
  bool created_folder = false;
  try {
    // stop cleanly on SIGINT and SIGTERM: the handler only sets a flag
    struct sigaction action {};
    action.sa_handler = RequestStop;
    action.sa_flags = SA_RESTART;
    sigemptyset(&action.sa_mask);
    sigaction(SIGINT, &action, nullptr);
    sigaction(SIGTERM, &action, nullptr);

    // the bus first: a bad URL or log is refused before anything is created on disk (on a log
    // file it only reads, live it is a reliable consumer; it listens once subscribed, below)
    BusOptions bus_options;
    bus_options.drop_receive_fraction = flags.fault_drop;
    bus_options.fault_seed = 0xC0C0;
    bus_options.key_file = flags.bus_key_file;
    bus_options.open_bus = flags.open_bus;
    bus_options.replay = flags.replay;
    bus_owner = std::make_unique<Bus>(ResolveLcmUrl(flags.lcm_url), bus_options);
    Bus& bus = *bus_owner;
    // then the dataset: a folder that is not empty is this writer's dataset to resume, or refused
    created_folder = CheckOutputFolder(program, flags);
    writer = program.open(flags);
    if (flags.resume) {
      std::printf("%s: resumed %s: %lld scenes stored%s\n", name_text, flags.out.c_str(),
                  static_cast<long long>(writer->num_images()),
                  writer->truncated_journal_bytes() > 0
                      ? (", cut a torn last record of " +
                         std::to_string(writer->truncated_journal_bytes()) + " bytes")
                            .c_str()
                      : "");
    }

    const std::string name = ConsumerName(program.name, flags.out);
    if (bus.url().rfind("file://", 0) != 0) {
      SceneClientOptions client_options;
      client_options.name = name;
      client_options.window = static_cast<int32_t>(flags.window);
      client_options.max_scenes = flags.count;
      client = std::make_unique<SceneClient>(&bus, client_options);
      for (const auto& [generator_id, seqs] : writer->StoredSeqs()) {
        client->Restore(generator_id, seqs);
      }
      // the runs the dataset holds go out with the credits: a generator of another run
      // (--seed or config) refuses to continue it
      for (const auto& [generator_id, run] : writer->Runs()) client->SetRun(generator_id, run);
    }

    // each generator's run, from its STACKGEN_CONFIG: recorded with its first scene stored (and
    // sent with the credits); a generator whose run differs from the one the dataset holds for
    // its id gets its scenes refused
    std::map<int32_t, std::string> heard_runs;
    std::set<int32_t> foreign_runs;
    // when a generator was last heard (its config every second, or a scene): a writer that
    // hears none for --warn-silent seconds says so
    auto generator_heard_at = std::chrono::steady_clock::now();
    bool warned_silent = false;
    bus.Subscribe<config_text>(
        kConfigChannel,
        [&](const config_text& config) {
          const int32_t generator_id = config.header.generator_id;
          if (generator_id < 0 || generator_id > kMaxGeneratorId || config.header.seed < 0) {
            return;
          }
          generator_heard_at = std::chrono::steady_clock::now();
          const std::string run = RunName(config.header.seed, config.path, config.pbtxt);
          const auto stored = writer->Runs().find(generator_id);
          if (stored == writer->Runs().end()) {
            if (heard_runs.size() < 1024 || heard_runs.count(generator_id) != 0) {
              heard_runs[generator_id] = run;
            }
          } else if (SameRun(stored->second, run)) {
            foreign_runs.erase(generator_id);
          } else if (foreign_runs.insert(generator_id).second) {
            std::fprintf(stderr,
                         "%s: refusing the scenes of generator %d: it runs %s, but %s holds "
                         "scenes of %s\n",
                         name_text, generator_id, run.c_str(), flags.out.c_str(),
                         stored->second.c_str());
          }
        },
        16, [](const std::string&) {});
    if (program.subscribe) program.subscribe(bus, *writer);

    // counters of what did not make it into the dataset
    int64_t decode_errors = 0;
    int64_t invalid_scenes = 0;
    int64_t duplicates = 0;
    // reliable: bad copies received of seqs not stored yet
    BadCopies bad_copies;
    const bool group_commit = flags.group_commit > 1;
    const auto enough = [&] {
      return flags.count > 0 && writer->num_images() + writer->num_staged() >= flags.count;
    };
    // makes the staged scenes durable, then credits them
    const auto commit = [&] {
      for (const auto& [generator_id, seq] : writer->Commit()) {
        if (client) client->Stored(generator_id, seq);
      }
    };

    bus.Subscribe<scene>(
        kSceneChannel,
        [&](const scene& scene) {
          generator_heard_at = std::chrono::steady_clock::now();
          // once --count scenes are stored, later ones in the same batch are left out
          if (enough()) return;
          const int32_t generator_id = scene.header.generator_id;
          const int64_t seq = scene.header.seq;
          if (foreign_runs.count(generator_id) != 0) {
            ++invalid_scenes;
            return;
          }
          // its generator's run, heard before, goes with the first scene stored
          if (writer->Runs().count(generator_id) == 0) {
            const auto heard = heard_runs.find(generator_id);
            if (heard != heard_runs.end()) {
              writer->SetRun(generator_id, heard->second);
              if (client) client->SetRun(generator_id, heard->second);
            }
          }
          // the writer first: it checks the scene whole (its images decoded) and refuses a
          // repeat. A copy that fails the checks tells the client nothing, so a damaged or a
          // stranger's copy cannot take the real scene's place: that seq is asked for again,
          // and given up (skipped) only after BadCopies::kCopies bad copies of it
          bool added = false;
          try {
            added = writer->Add(scene);
          } catch (const InvalidSceneError& error) {
            if (++invalid_scenes <= kMaxReportedErrors) {
              std::fprintf(stderr, "%s: refused a scene: %s\n", name_text, error.what());
            }
            if (client) {
              if (bad_copies.Note(generator_id, seq) && client->Received(generator_id, seq)) {
                client->Skipped(generator_id, seq);
              }
              client->Service();
            }
            return;
          }
          // the client tracks seqs (and counts repeats); a scene the writer holds already that
          // the client has not seen (stored before it started) needs no asking again
          const bool fresh = !client || client->Received(generator_id, seq);
          if (added) {
            if (client) bad_copies.Forget(generator_id, seq);
            // credited once durable: at once without group commits (Add made it durable),
            // else with its group
            if (!group_commit) {
              if (client) client->Stored(generator_id, seq);
            } else if (writer->num_staged() >= flags.group_commit) {
              commit();
            }
          } else if (!client) {
            ++duplicates;
          } else if (fresh) {
            client->Skipped(generator_id, seq);
          }
          if (client) client->Service();
        },
        kQueueCapacity,
        [&](const std::string& text) {
          if (++decode_errors <= kMaxReportedErrors) {
            std::fprintf(stderr, "%s: skipped a message: %s\n", name_text, text.c_str());
          }
        });

    std::printf("%s: listening on %s channel %s, writing %s\n", name_text, bus.url().c_str(),
                kSceneChannel, flags.out.c_str());
    std::fflush(stdout);

    // publishes the counters on STACKGEN_STATUS
    int64_t stored_at_last_status = writer->num_images();
    auto last_status = std::chrono::steady_clock::now();
    const auto publish_status = [&](std::chrono::steady_clock::time_point now) {
      const double seconds = std::chrono::duration<double>(now - last_status).count();
      ConsumerReport report;
      report.process = program.name;
      report.name = name;
      report.scenes_held = writer->num_images();
      report.delivery = client ? client->counters() : DeliveryCounters{};
      report.scenes = report.delivery.stored;
      report.rate_hz = seconds > 0 ? (writer->num_images() - stored_at_last_status) / seconds : 0;
      report.bad_messages = decode_errors + invalid_scenes;
      bus.Publish(kStatusChannel, ConsumerStatus(bus, report));
      last_status = now;
      stored_at_last_status = writer->num_images();
    };

    // handle scenes until enough are stored or a signal arrives
    const bool show_progress = isatty(STDERR_FILENO) != 0;
    const auto start = std::chrono::steady_clock::now();
    const int64_t stored_at_start = writer->num_images();
    auto last_progress = start;
    const std::vector<std::string> generator_channels = {kSceneChannel, kConfigChannel};
    while (!stop_requested && !enough() && !bus.log_ended()) {
      // with scenes staged, only those already waiting: the group ends when none is left
      bus.HandleFor(writer->num_staged() > 0 ? 0 : 50);
      commit();
      const std::string mismatch = bus.KeyMismatch(generator_channels, kKeyMismatchS);
      if (!mismatch.empty()) throw std::runtime_error(mismatch);
      if (client) client->Service();
      const auto now = std::chrono::steady_clock::now();
      const double silent_s = std::chrono::duration<double>(now - generator_heard_at).count();
      if (silent_s < 1) {
        warned_silent = false;
      } else if (!warned_silent && flags.warn_silent_s > 0 && silent_s >= flags.warn_silent_s &&
                 bus.url().rfind("file://", 0) != 0) {
        warned_silent = true;
        if (show_progress) std::fprintf(stderr, "\n");
        std::fprintf(stderr,
                     "%s: no generator heard for %d s on %s (no scene, no config): is stackgen "
                     "running with this --lcm-url (the same port) and %s? still waiting\n",
                     name_text, static_cast<int>(silent_s), bus.url().c_str(),
                     bus.keyed() ? ("the bus key " + bus.key_file() + " (key id " +
                                    KeyIdText(bus.key_id()) + ")")
                                       .c_str()
                                 : "--open-bus (this writer checks no key)");
      }
      if (client && now - last_status >= std::chrono::seconds(1)) publish_status(now);
      if (show_progress && now - last_progress >= std::chrono::milliseconds(500)) {
        last_progress = now;
        const double seconds = std::chrono::duration<double>(now - start).count();
        const double rate = (writer->num_images() - stored_at_start) / std::max(seconds, 1e-9);
        std::string eta;
        if (flags.count > 0 && rate > 0) {
          eta = ", ETA " + FormatDuration((flags.count - writer->num_images()) / rate);
        }
        std::fprintf(stderr, "\r%s: %lld scenes, %.1f scenes/s%s   ", name_text,
                     static_cast<long long>(writer->num_images()), rate, eta.c_str());
      }
    }
    if (show_progress) std::fprintf(stderr, "\n");
    // a log whose scenes were all refused for their key is an error, not an empty dataset
    if (bus.log_ended() && writer->num_images() == stored_at_start) {
      const std::string mismatch = bus.KeyMismatch(generator_channels, 0);
      if (!mismatch.empty()) throw std::runtime_error(mismatch);
    }

    // generators stop waiting for us; a valid dataset of what arrived
    commit();
    if (client) {
      publish_status(std::chrono::steady_clock::now());
      client->Leave();
    }
    writer->Finish();
    for (const auto& [generator_id, lost] : writer->LostPerGenerator()) {
      if (lost > 0) {
        std::fprintf(stderr, "%s: generator %d: %lld scenes lost\n", name_text, generator_id,
                     static_cast<long long>(lost));
      }
    }
    if (decode_errors > 0 || invalid_scenes > 0) {
      std::fprintf(stderr, "%s: skipped %lld undecodable messages, refused %lld invalid scenes\n",
                   name_text, static_cast<long long>(decode_errors),
                   static_cast<long long>(invalid_scenes));
    }
    if (bus.url().rfind("udpm://", 0) == 0) {
      std::printf("%s: %s\n", name_text, ReceiveSummary(bus.receive_counters()).c_str());
    }
    if (bus.keyed()) {
      const int64_t stored = writer->num_images();
      std::printf("%s: bus key: %.3f ms per scene stored signing and checking messages; %s\n",
                  name_text,
                  stored > 0 ? bus.auth_seconds() * 1e3 / static_cast<double>(stored) : 0.0,
                  RefusedSummary(bus.auth_counters()).c_str());
    }
    if (client) {
      const DeliveryCounters counters = client->counters();
      std::printf(
          "%s: delivery: %lld scenes received, %lld stored, %lld received twice, %lld asked "
          "for again, %lld missing, %lld messages dropped on purpose\n",
          name_text, static_cast<long long>(counters.received),
          static_cast<long long>(counters.stored), static_cast<long long>(counters.duplicates),
          static_cast<long long>(counters.reasked), static_cast<long long>(counters.lost),
          static_cast<long long>(bus.fault_dropped()));
    } else if (duplicates > 0) {
      std::printf("%s: %lld scenes received twice, stored once\n", name_text,
                  static_cast<long long>(duplicates));
    }
    std::printf("%s\n", program.summary(*writer).c_str());
    std::fflush(stdout);
    return 0;
  } catch (const std::exception& error) {
    // a write error (full disk, ...): leave what is stored valid and say so. No leaving credit:
    // the generators wait (up to their --consumer-timeout) for this writer to be resumed.
    std::string state;
    if (writer && writer->num_images() == 0 && !flags.resume) {
      // nothing stored: nothing left behind (the folder was empty or absent when it started)
      writer.reset();
      RemoveDatasetFolder(flags.out, created_folder);
    } else if (writer && (writer->num_images() > 0 || flags.resume)) {
      try {
        writer->Finish();
        state = "; " + flags.out + " holds " + std::to_string(writer->num_images()) + " scenes (" +
                writer->finished_files() + " written)";
      } catch (const std::exception& finish_error) {
        state = "; " + writer->finished_files() + " not updated (" +
                std::string(finish_error.what()) + ")";
      }
      state += "; the journal holds every scene stored: fix the cause and run again with --resume";
    }
    std::fprintf(stderr, "%s: error: %s%s\n", name_text, error.what(), state.c_str());
    return 1;
  }
}

}  // namespace stackgen
