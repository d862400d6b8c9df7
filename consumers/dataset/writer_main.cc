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
#include "contract/scene_contract.h"
#include "session/consumer.h"
#include "session/delivery.h"

namespace stackgen {
namespace {

// scenes LCM keeps waiting for us while a scene is written
constexpr int kQueueCapacity = 1000;
// generators heard for this long that all use another bus key are said (seconds): they publish
// their config every second, so one with the right key would have been heard by then
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

void AddWriterFlags(FlagParser* parser, WriterFlags* flags) {
  parser->String("--out", &flags->out, "a folder");
  parser->Require("--out");
  parser->Int("--count", &flags->count, 0, INT64_MAX);
  parser->Int("--first-seq", &flags->first_seq, 0, kMaxSeq);
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
             "  --first-seq A         take each generator's scenes from seq A on (default 0): the\n"
             "                        lower seqs are not this dataset's and are never waited for; "
             "with\n"
             "                        --count N it holds seqs A..A+N-1 of a generator started "
             "with\n"
             "                        stackgen --first-seq A (one task of a job: tools/task).\n"
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

namespace {

// One writer's bus life, from opening the bus and the dataset to the summary: the delivery
// client, each generator's run, the scene handler (the writer's checks, bad copies, duplicates,
// group commits), status, progress and the silent-generator warning.
class WriterSession {
 public:
  WriterSession(const WriterProgram& program, const WriterFlags& flags)
      : program_(program),
        flags_(flags),
        name_text_(program.name.c_str()),
        clock_(program.clock != nullptr ? *program.clock : SteadyClock()) {}

  // the bus first: a bad URL or log is refused before anything is created on disk (on a log
  // file it only reads, live it is a reliable consumer; it listens once subscribed); then the
  // dataset: a folder that is not empty is this writer's dataset to resume, or refused
  void Open() {
    auto bus = std::make_unique<Bus>(ResolveLcmUrl(flags_.lcm_url),
                                     ConsumerBusOptions(flags_.fault_drop, flags_.bus_key_file,
                                                        flags_.open_bus, flags_.replay, 0xC0C0));
    created_folder_ = CheckOutputFolder(program_, flags_);
    writer_ = program_.open(flags_);
    if (flags_.resume) {
      std::printf("%s: resumed %s: %lld scenes stored%s\n", name_text_, flags_.out.c_str(),
                  static_cast<long long>(writer_->num_images()),
                  writer_->truncated_journal_bytes() > 0
                      ? (", cut a torn last record of " +
                         std::to_string(writer_->truncated_journal_bytes()) + " bytes")
                            .c_str()
                      : "");
    }
    // live, a reliable consumer; on a log file it only reads. A writer that cannot take what
    // the generators publish (another bus key, or none) stops with one line
    ConsumerSessionOptions options;
    options.process = program_.name;
    options.name = ConsumerName(program_.name, flags_.out);
    options.reliable = true;
    options.client.window = static_cast<int32_t>(flags_.window);
    options.client.max_scenes = flags_.count;
    options.client.first_seq = flags_.first_seq;
    options.key_mismatch_s = kKeyMismatchS;
    options.strict_keys = true;
    options.clock = &clock_;
    session_ = std::make_unique<ConsumerSession>(std::move(bus), options);
    for (const auto& [generator_id, seqs] : writer_->StoredSeqs()) {
      session_->Restore(generator_id, seqs);
    }
    // the runs the dataset holds go out with the credits: a generator of another run (--seed
    // or config) refuses to continue it
    for (const auto& [generator_id, run] : writer_->Runs()) session_->SetRun(generator_id, run);
  }

  void Subscribe() {
    generator_heard_at_ = clock_.Now();
    Bus& bus = session_->bus();
    bus.Subscribe<config_text>(
        kConfigChannel, [this](const config_text& config) { OnConfig(config); }, 16,
        [](const std::string&) {});
    bus.Subscribe<status>(
        kStatusChannel, [this](const status& message) { OnStatus(message); }, 64,
        [](const std::string&) {});
    if (program_.subscribe) program_.subscribe(bus, *writer_);
    session_->SubscribeScenes(
        kSceneChannel, [this](const scene& message) { OnScene(message); }, kQueueCapacity,
        [this](const std::string& text) {
          if (session_->undecodable() <= kMaxReportedErrors) {
            std::fprintf(stderr, "%s: skipped a message: %s\n", name_text_, text.c_str());
          }
        });
    std::printf("%s: listening on %s channel %s, writing %s; %s\n", name_text_, bus.url().c_str(),
                kSceneChannel, flags_.out.c_str(),
                bus.state().keyed() ? KeyText().c_str() : "open bus: no key");
    std::fflush(stdout);
  }

  // handles scenes until enough are stored, a signal arrives or the log ends
  void Loop() {
    Bus& bus = session_->bus();
    start_ = clock_.Now();
    stored_at_start_ = writer_->num_images();
    last_progress_ = start_;
    while (!stop_requested && !Enough() && !bus.state().log_ended()) {
      // with scenes staged, only those already waiting: the group ends when none is left
      bus.HandleFor(writer_->num_staged() > 0 ? 0 : 50);
      Commit();
      session_->Service(writer_->num_images(), session_->delivery().stored);
      const auto now = clock_.Now();
      WarnIfSilent(now);
      ShowProgress(now);
    }
    if (show_progress_) std::fprintf(stderr, "\n");
    // a log whose scenes were all refused for their key is an error, not an empty dataset
    if (bus.state().log_ended() && writer_->num_images() == stored_at_start_) session_->CheckKeys();
    if (Enough() && !stop_requested) AwaitCompletion();
  }

  // --count scenes are stored, but the dataset lacks something else heard on the bus (a
  // model lost on the way): listen on for it, crediting as before, up to kCompletionWaitS or
  // the end of a log; said on stderr when it does not come
  void AwaitCompletion() {
    if (!program_.missing || program_.missing(*writer_).empty()) return;
    Bus& bus = session_->bus();
    const Clock::TimePoint until =
        clock_.Now() + std::chrono::duration_cast<Clock::TimePoint::duration>(
                           std::chrono::duration<double>(kCompletionWaitS));
    while (!stop_requested && !bus.state().log_ended() && clock_.Now() < until &&
           !program_.missing(*writer_).empty()) {
      bus.HandleFor(50);
      session_->Service(writer_->num_images(), session_->delivery().stored);
    }
    const std::string missing = program_.missing(*writer_);
    if (missing.empty()) return;
    const std::string when =
        bus.state().log_ended() ? "before the end of the log"
        : stop_requested        ? "before a signal stopped the wait"
                                : "within " + std::to_string(static_cast<int>(kCompletionWaitS)) +
                                      " s of the last scene";
    std::fprintf(stderr, "%s: warning: %lld scenes stored, but %s was not heard %s: the dataset "
                 "lacks it\n", name_text_, static_cast<long long>(writer_->num_images()),
                 missing.c_str(), when.c_str());
  }

  // generators stop waiting for us (and a monitor sees we ended: our --count stored, or
  // stopped: a signal); a valid dataset of what arrived; the summary
  void Finish() {
    Commit();
    session_->Leave(writer_->num_images(), session_->delivery().stored,
                    Enough() ? kRunEnded : kRunStopped);
    writer_->Finish();
    PrintSummary();
  }

  // a write error (full disk, ...): leave what is stored valid and say so. No leaving credit:
  // the generators wait (up to their --consumer-timeout) for this writer to be resumed.
  int Fail(const std::exception& error) {
    std::string state;
    if (writer_ && writer_->num_images() == 0 && !flags_.resume) {
      // nothing stored: nothing left behind (the folder was empty or absent when it started)
      writer_.reset();
      RemoveDatasetFolder(flags_.out, created_folder_);
    } else if (writer_ && (writer_->num_images() > 0 || flags_.resume)) {
      try {
        writer_->Finish();
        state = "; " + flags_.out + " holds " + std::to_string(writer_->num_images()) +
                " scenes (" + writer_->finished_files() + " written)";
      } catch (const std::exception& finish_error) {
        state = "; " + writer_->finished_files() + " not updated (" +
                std::string(finish_error.what()) + ")";
      }
      state += "; the journal holds every scene stored: fix the cause and run again with --resume";
    }
    std::fprintf(stderr, "%s: error: %s%s\n", name_text_, error.what(), state.c_str());
    return 1;
  }

 private:
  // "bus key FILE (key id ID)": what a keyed writer checks with, in its lines
  std::string KeyText() const {
    const BusState& state = session_->bus().state();
    return "bus key " + state.key_file() + " (key id " + KeyIdText(state.key_id()) + ")";
  }

  bool Enough() const {
    return flags_.count > 0 && writer_->num_images() + writer_->num_staged() >= flags_.count;
  }

  // makes the staged scenes durable, then credits them
  void Commit() {
    for (const auto& [generator_id, seq] : writer_->Commit()) session_->Stored(generator_id, seq);
  }

  // each generator's run, from its STACKGEN_CONFIG: recorded with its first scene stored (and
  // sent with the credits); a generator whose run differs from the one the dataset holds for
  // its id gets its scenes refused
  void OnConfig(const config_text& config) {
    const int32_t generator_id = config.header.generator_id;
    if (generator_id < 0 || generator_id > kMaxGeneratorId || config.header.seed < 0) return;
    generator_heard_at_ = clock_.Now();
    const std::string run = RunName(config.header.seed, config.path, config.pbtxt);
    const auto stored = writer_->Runs().find(generator_id);
    if (stored == writer_->Runs().end()) {
      if (heard_runs_.size() < 1024 || heard_runs_.count(generator_id) != 0) {
        heard_runs_[generator_id] = run;
      }
    } else if (SameRun(stored->second, run)) {
      foreign_runs_.erase(generator_id);
    } else if (foreign_runs_.insert(generator_id).second) {
      std::fprintf(stderr,
                   "%s: refusing the scenes of generator %d: it runs %s, but %s holds "
                   "scenes of %s\n",
                   name_text_, generator_id, run.c_str(), flags_.out.c_str(),
                   stored->second.c_str());
    }
  }

  // a generator that stopped before its end (a signal, an error such as a stall) leaves this
  // writer short: said once per stop, with what it now waits for, not a silent wait
  void OnStatus(const status& message) {
    if (message.process != "stackgen" || message.header.generator_id < 0 ||
        message.header.generator_id > kMaxGeneratorId) {
      return;
    }
    const int32_t generator_id = message.header.generator_id;
    if (message.run_state != kRunStopped) {
      if (message.run_state == kRunRunning) stopped_said_.erase(generator_id);
      return;
    }
    if (Enough() || stopped_said_.size() >= 1024 || !stopped_said_.insert(generator_id).second) {
      return;
    }
    if (show_progress_) std::fprintf(stderr, "\n");
    std::fprintf(stderr,
                 "%s: generator %d (%s) stopped before its end; %lld%s scenes stored: waiting for "
                 "a generator to continue the run (stackgen --resume with its --seed and "
                 "--config); Ctrl-C stops with a valid dataset, and %s --resume continues it\n",
                 name_text_, generator_id, message.name.c_str(),
                 static_cast<long long>(writer_->num_images()),
                 flags_.count > 0 ? (" of " + std::to_string(flags_.count)).c_str() : "",
                 name_text_);
  }

  void OnScene(const scene& scene) {
    generator_heard_at_ = clock_.Now();
    // once --count scenes are stored, later ones in the same batch are left out
    if (Enough()) return;
    const int32_t generator_id = scene.header.generator_id;
    const int64_t seq = scene.header.seq;
    // a seq before --first-seq belongs to another dataset (another task's share)
    if (seq < flags_.first_seq) return;
    if (foreign_runs_.count(generator_id) != 0) {
      session_->CountRefused();
      return;
    }
    // its generator's run, heard before, goes with the first scene stored
    if (writer_->Runs().count(generator_id) == 0) {
      const auto heard = heard_runs_.find(generator_id);
      if (heard != heard_runs_.end()) {
        writer_->SetRun(generator_id, heard->second);
        session_->SetRun(generator_id, heard->second);
      }
    }
    // the writer first: it checks the scene whole (its images decoded) and refuses a repeat;
    // a copy that fails the checks goes to the session's bad-copy policy
    const bool reliable = session_->reliable();
    bool added = false;
    try {
      added = writer_->Add(scene);
    } catch (const InvalidSceneError& error) {
      if (session_->refused() < kMaxReportedErrors) {
        std::fprintf(stderr, "%s: refused a scene: %s\n", name_text_, error.what());
      }
      session_->Refuse(generator_id, seq);
      session_->Credit();
      return;
    }
    // the client tracks seqs (and counts repeats); a scene the writer holds already that the
    // client has not seen (stored before it started) needs no asking again
    const bool fresh = !reliable || session_->Fresh(generator_id, seq);
    if (added) {
      // credited once durable: at once without group commits (Add made it durable), else with
      // its group
      if (flags_.group_commit <= 1) {
        session_->Stored(generator_id, seq);
      } else if (writer_->num_staged() >= flags_.group_commit) {
        Commit();
      }
    } else if (!reliable) {
      session_->CountRepeat();
    } else if (fresh) {
      session_->Skipped(generator_id, seq);
    }
    session_->Credit();
  }

  // when no generator was heard (its config every second, or a scene) for --warn-silent
  // seconds, says so once
  void WarnIfSilent(Clock::TimePoint now) {
    const double silent_s = std::chrono::duration<double>(now - generator_heard_at_).count();
    if (silent_s < 1) {
      warned_silent_ = false;
    } else if (!warned_silent_ && flags_.warn_silent_s > 0 && silent_s >= flags_.warn_silent_s &&
               session_->live() && session_->KeyHint().empty() && stopped_said_.empty()) {
      // (generators of another key were heard, and said: the session's warning)
      warned_silent_ = true;
      const Bus& bus = session_->bus();
      if (show_progress_) std::fprintf(stderr, "\n");
      std::fprintf(stderr,
                   "%s: no generator heard for %d s on %s (no scene, no config): is stackgen "
                   "running with this --lcm-url (the same port) and %s? still waiting\n",
                   name_text_, static_cast<int>(silent_s), bus.url().c_str(),
                   bus.state().keyed() ? ("the " + KeyText()).c_str()
                                       : "--open-bus (this writer checks no key)");
    }
  }

  // a progress line on a terminal, twice a second
  void ShowProgress(Clock::TimePoint now) {
    if (!show_progress_ || now - last_progress_ < std::chrono::milliseconds(500)) return;
    last_progress_ = now;
    const double seconds = std::chrono::duration<double>(now - start_).count();
    const double rate = (writer_->num_images() - stored_at_start_) / std::max(seconds, 1e-9);
    std::string eta;
    if (flags_.count > 0 && rate > 0) {
      eta = ", ETA " + FormatDuration((flags_.count - writer_->num_images()) / rate);
    }
    std::fprintf(stderr, "\r%s: %lld scenes, %.1f scenes/s%s   ", name_text_,
                 static_cast<long long>(writer_->num_images()), rate, eta.c_str());
  }

  void PrintSummary() const {
    for (const auto& [generator_id, lost] : writer_->LostPerGenerator()) {
      if (lost > 0) {
        std::fprintf(stderr, "%s: generator %d: %lld scenes lost\n", name_text_, generator_id,
                     static_cast<long long>(lost));
      }
    }
    const Bus& bus = session_->bus();
    if (session_->undecodable() > 0 || session_->refused() > 0) {
      std::fprintf(stderr, "%s: skipped %lld undecodable messages, refused %lld invalid scenes\n",
                   name_text_, static_cast<long long>(session_->undecodable()),
                   static_cast<long long>(session_->refused()));
    }
    if (bus.url().rfind("udpm://", 0) == 0) {
      std::printf("%s: %s\n", name_text_, ReceiveSummary(bus.state().receive_counters()).c_str());
    }
    if (bus.state().keyed()) {
      const int64_t stored = writer_->num_images();
      std::printf("%s: bus key: %.3f ms per scene stored signing and checking messages; %s\n",
                  name_text_,
                  stored > 0 ? bus.state().auth_seconds() * 1e3 / static_cast<double>(stored) : 0.0,
                  RefusedSummary(bus.state().auth_counters()).c_str());
    }
    if (session_->reliable()) {
      const DeliveryCounters counters = session_->delivery();
      std::printf(
          "%s: delivery: %lld scenes received, %lld stored, %lld received twice, %lld asked "
          "for again, %lld missing, %lld messages dropped on purpose\n",
          name_text_, static_cast<long long>(counters.received),
          static_cast<long long>(counters.stored), static_cast<long long>(counters.duplicates),
          static_cast<long long>(counters.reasked), static_cast<long long>(counters.lost),
          static_cast<long long>(bus.state().fault_dropped()));
    } else if (session_->repeats() > 0) {
      std::printf("%s: %lld scenes received twice, stored once\n", name_text_,
                  static_cast<long long>(session_->repeats()));
    }
    std::printf("%s\n", program_.summary(*writer_).c_str());
    std::fflush(stdout);
  }

  const WriterProgram& program_;
  const WriterFlags& flags_;
  const char* const name_text_;
  Clock& clock_;  // the waits, warnings, progress and the session's status period
  const bool show_progress_ = isatty(STDERR_FILENO) != 0;
  // the writer outlives the session (the error path still finishes the dataset)
  std::unique_ptr<DatasetSink> writer_;
  std::unique_ptr<ConsumerSession> session_;
  bool created_folder_ = false;
  std::map<int32_t, std::string> heard_runs_;
  std::set<int32_t> foreign_runs_;
  std::set<int32_t> stopped_said_;  // generators said to have stopped before their end
  Clock::TimePoint generator_heard_at_;
  bool warned_silent_ = false;
  Clock::TimePoint start_;
  Clock::TimePoint last_progress_;
  int64_t stored_at_start_ = 0;
};

}  // namespace

int RunWriter(const WriterProgram& program, const WriterFlags& flags) {
  // a file too large for RLIMIT_FSIZE is a write error with a message, not a silent kill
  std::signal(SIGXFSZ, SIG_IGN);
  WriterSession session(program, flags);
  try {
    // stop cleanly on SIGINT and SIGTERM: the handler only sets a flag
    StopOnSignals(RequestStop);
    session.Open();
    session.Subscribe();
    session.Loop();
    session.Finish();
    return 0;
  } catch (const std::exception& error) {
    return session.Fail(error);
  }
}

std::string ClassesText(const std::map<int32_t, std::string>& classes) {
  if (classes.empty()) return "no classes";
  std::string text;
  for (const auto& [class_id, class_name] : classes) {
    text += (text.empty() ? "classes " : ", ") + std::to_string(class_id) + " " + class_name;
  }
  return text;
}

}  // namespace stackgen
