#pragma once
// The program around a dataset writer (stackgen-coco, stackgen-bop): the flags they share, the
// bus, credits and resends as a reliable consumer, each generator's run, group commits, status,
// progress and the summary. A writer supplies only its dataset (a DatasetSink).

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "bus/bus.h"
#include "bus/clock.h"
#include "cli/flags.h"
#include "consumers/dataset/dataset_sink.h"

namespace stackgen {

/// The flags every dataset writer has.
struct WriterFlags {
  std::string out;
  int64_t count = 0;
  int64_t first_seq = 0;  // scenes of lower seqs are not this dataset's (one task of a job)
  std::string lcm_url;
  std::string bus_key_file;  // "": $STACKGEN_BUS_KEY_FILE, else this user's key
  bool open_bus = false;
  bool replay = false;
  bool resume = false;
  int64_t window = 8;
  int64_t group_commit = 16;
  double fault_drop = 0;
  int64_t warn_silent_s = 10;  // says so when no generator is heard this long; 0: never
};

/// Registers the WriterFlags on `parser`: --out (required), --count, --first-seq, --resume,
/// --lcm-url, --bus-key-file, --open-bus, --replay, --window, --group-commit, --fault-drop,
/// --warn-silent.
void AddWriterFlags(FlagParser* parser, WriterFlags* flags);

/// The help text of those flags, for a program's --help (`program` names its journal).
std::string WriterFlagsHelp(const std::string& journal);

/// What a writer program is.
struct WriterProgram {
  /// Its name in messages and credits: "stackgen-coco".
  std::string name;
  /// Its journal's file name in the dataset folder ("annotations.journal"): a folder that holds
  /// it is the program's dataset.
  std::string journal;
  /// Opens the dataset in flags.out (resumed with flags.resume). Called after the bus is open, so
  /// a bad URL or key leaves nothing on disk.
  std::function<std::unique_ptr<DatasetSink>(const WriterFlags&)> open;
  /// Optional: subscribes what else the writer needs from the bus (stackgen-bop: the models).
  std::function<void(Bus&, DatasetSink&)> subscribe;
  /// Optional: what the dataset still lacks once --count scenes are stored, "" when nothing
  /// (stackgen-bop: "the model of class 1"). The writer listens on for it, up to
  /// kCompletionWaitS seconds or the end of a log, before it finishes; still missing then,
  /// it says so on stderr.
  std::function<std::string(const DatasetSink&)> missing;
  /// The last line printed on success, after Finish: what the dataset holds.
  std::function<std::string(const DatasetSink&)> summary;
  /// The clock of the writer's waits, warnings, progress and status (bus/clock.h); null:
  /// SteadyClock(). Must outlive RunWriter.
  Clock* clock = nullptr;
};

/// How long a writer listens, once --count scenes are stored, for what WriterProgram::missing
/// names (seconds): a generator publishes its models every 5 s and again at its end.
inline constexpr double kCompletionWaitS = 6.0;

/// Runs a writer program to its end: stores the scenes on STACKGEN_SCENE until flags.count are
/// stored, SIGINT or SIGTERM, or the end of a file:// log; returns the exit status (0, or 1
/// after printing one error line; what is stored stays valid). Without --resume, flags.out must
/// be absent or empty: a writer never writes into a folder that is not its own dataset; with
/// it, the folder must hold the program's journal. A run that stops with an error before it
/// stored anything leaves no dataset behind.
int RunWriter(const WriterProgram& program, const WriterFlags& flags);

/// The classes of a dataset for a summary line: "classes 1 corner_connector, 2 dowel_pin" (the
/// class name a part was given, or its mesh file's; "no classes" when none was stored).
std::string ClassesText(const std::map<int32_t, std::string>& classes);

}  // namespace stackgen
