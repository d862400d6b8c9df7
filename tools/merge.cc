// stackgen-merge: assembles the datasets of one run (the shards of a cluster job made by
// tools/task, or any COCO or BOP datasets of the same config and seed) into one dataset, exactly
// once: every scene of the inputs once, no scene missing, the same files one process would have
// written for the same scenes. The inputs' journals are the record: their lines are joined in
// (generator id, seq) order into the new dataset's journal beside its image files (hard links, a
// copy across file systems), and the format's own writer (CocoWriter, BopWriter) resumes that
// dataset and writes the files derived from the journal (annotations.json; the chunk JSON files,
// models and camera of BOP; webdataset shards with --shards), all in a temporary folder renamed
// into place at the end.

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/flags.h"
#include "consumers/bop/bop_writer.h"
#include "consumers/coco/coco_writer.h"
#include "consumers/dataset/files.h"
#include "session/delivery.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kUsage = R"(usage: stackgen-merge --out DIR [--shards N] INPUT...

Assembles datasets of one run into one dataset at DIR, exactly once: the shards of a cluster job
(tools/task writes one per task, each a COCO or BOP dataset with its task.json), or any finished
datasets of stackgen-coco or stackgen-bop made with the same config and seed (a dataset whose
writer was stopped counts with the scenes its journal holds). The result holds
every scene of the inputs once and is the dataset one writer would have made from the same
scenes: the same image files and, byte for byte, the same annotations.json (COCO) or chunk JSON
files, models and camera.json (BOP).

Refused, with one line naming the input, before anything is written: an input that is not a
dataset (no journal), is still being written (its writer holds the journal), or is damaged (a
journal torn by a kill, a recorded file missing), inputs of
different formats, splits or labelling options, a scene of another run (config or seed), a
scene held by two inputs, and for task shards a task that is missing or given twice (every task
0..T-1 of the job must be there).

flags:
  --out DIR    the merged dataset: a folder that does not exist yet, or an empty one; written
               as DIR.merging and renamed when whole
  --shards N   also webdataset tar shards of at most N images, 1..1000, as the writers'
               --shards (default: none)
  --help       this text
)";

enum class Format { kCoco, kBop };

const char* JournalName(Format format) {
  return format == Format::kCoco ? "annotations.journal" : "bop.journal";
}

// one scene recorded in an input's journal
struct Recorded {
  int32_t generator_id = 0;
  int64_t seq = 0;
  std::string run;
  uint64_t offset = 0;             // its journal line: where it starts in the input's journal
  uint64_t length = 0;             // and its bytes, without the '\n'
  std::vector<std::string> files;  // relative to the input folder
  size_t input = 0;
};

// tools/task's task.json: which share of the job an input holds
struct TaskShard {
  int64_t task = 0;
  int64_t tasks = 0;
  int64_t generator_id = 0;
  int64_t first_seq = 0;
  int64_t count = 0;
  int64_t total = 0;
};

struct Input {
  fs::path dir;
  Format format = Format::kCoco;
  std::string options;  // the labelling options its lines record (COCO), or its split (BOP)
  json coco_options;    // COCO: min_visib_fract (null: none) and polygons of its first line
  std::vector<Recorded> scenes;
  std::optional<TaskShard> task;
  std::shared_ptr<const int> lock;  // its journal, held (shared) while merging
};

[[noreturn]] void Fail(const std::string& text) { throw std::runtime_error(text); }

// the fields of a journal line merge needs; `where` names the line in errors
Recorded ParseLine(Input* input, const std::string& line, const std::string& where,
                   std::string* options) {
  json record;
  try {
    record = json::parse(line);
    Recorded scene;
    const json& head = record.at("scene");
    scene.generator_id = head.at("generator_id").get<int32_t>();
    scene.seq = head.at("seq").get<int64_t>();
    scene.run = head.value("run", std::string());
    if (input->format == Format::kCoco) {
      scene.files.push_back("images/" + record.at("image").at("file_name").get<std::string>());
      *options = "min_visib_fract " + head.at("min_visib_fract").dump() +
                 (head.value("polygons", false) ? ", --polygons" : ", RLE");
      if (input->scenes.empty()) {
        input->coco_options = {{"min_visib_fract", head.at("min_visib_fract")},
                               {"polygons", head.value("polygons", false)}};
      }
    } else {
      scene.files = head.at("files").get<std::vector<std::string>>();
      if (scene.files.empty()) Fail("no files");
      *options = "split " + scene.files.front().substr(0, scene.files.front().find('/'));
    }
    scene.length = line.size();
    return scene;
  } catch (const std::exception& error) {
    Fail(where + ": not a stackgen journal record (" + error.what() + ")");
  }
}

// `journal` locked against a writer while merging (a writer holds its journal's lock for good
// while it runs): refused when one holds it now
std::shared_ptr<const int> LockShared(const fs::path& journal) {
  const int fd = open(journal.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) Fail(journal.string() + ": cannot open it: " + std::strerror(errno));
  if (flock(fd, LOCK_SH | LOCK_NB) != 0) {
    const int error = errno;
    close(fd);
    Fail(journal.parent_path().string() + ": still being written (its writer holds " +
         journal.filename().string() +
         (error == EWOULDBLOCK ? "" : ": " + std::string(std::strerror(error))) +
         "): wait for it to finish, or stop it");
  }
  return std::shared_ptr<const int>(new int(fd), [](const int* held) {
    close(*held);
    delete held;
  });
}

// calls on_line(line, offset) for each line of the journal at `path`, one at a time (a merge
// of millions of scenes holds no journal in memory); a last line without its '\n' is a record
// torn by a kill
void ForEachJournalLine(const fs::path& path,
                        const std::function<void(const std::string&, uint64_t)>& on_line) {
  std::ifstream file(path, std::ios::binary);
  if (!file) Fail(path.string() + ": cannot read it");
  std::string line;
  uint64_t offset = 0;
  while (std::getline(file, line)) {
    if (file.eof()) {
      Fail(path.string() +
           " ends in a torn record (its writer was stopped by a kill): finish that dataset with "
           "--resume first");
    }
    on_line(line, offset);
    offset += line.size() + 1;
  }
  if (file.bad()) Fail(path.string() + ": cannot read it");
}

std::optional<TaskShard> ReadTask(const fs::path& dir) {
  const fs::path path = dir / "task.json";
  if (!fs::exists(path)) return std::nullopt;
  try {
    std::ifstream file(path);
    const json record = json::parse(file);
    TaskShard task;
    task.task = record.at("task").get<int64_t>();
    task.tasks = record.at("tasks").get<int64_t>();
    task.generator_id = record.at("generator_id").get<int64_t>();
    task.first_seq = record.at("first_seq").get<int64_t>();
    task.count = record.at("count").get<int64_t>();
    task.total = record.at("total").get<int64_t>();
    if (task.tasks < 1 || task.task < 0 || task.task >= task.tasks || task.count < 0) {
      Fail("task " + std::to_string(task.task) + " of " + std::to_string(task.tasks));
    }
    return task;
  } catch (const std::exception& error) {
    Fail(path.string() + ": not a task record of tools/task (" + error.what() + ")");
  }
}

// an input folder read whole: its format, its journal's records, its task; refused unless it
// is a finished dataset whose recorded files are all there
Input LoadInput(const fs::path& dir, size_t index) {
  Input input;
  input.dir = dir;
  const bool coco = fs::exists(dir / JournalName(Format::kCoco));
  const bool bop = fs::exists(dir / JournalName(Format::kBop));
  if (!fs::is_directory(dir)) Fail(dir.string() + ": no such folder");
  if (coco == bop) {
    Fail(dir.string() + ": not a dataset of stackgen-coco or stackgen-bop (" +
         (coco ? "both journals" : "no annotations.journal or bop.journal") + ")");
  }
  input.format = coco ? Format::kCoco : Format::kBop;
  const fs::path journal = dir / JournalName(input.format);
  input.lock = LockShared(journal);
  ForEachJournalLine(journal, [&](const std::string& line, uint64_t offset) {
    const std::string where = journal.string() + " line " + std::to_string(input.scenes.size() + 1);
    std::string options;
    Recorded scene = ParseLine(&input, line, where, &options);
    if (input.scenes.empty()) input.options = options;
    if (options != input.options) {
      Fail(where + ": written with " + options + ", its first line with " + input.options);
    }
    for (const std::string& file : scene.files) {
      if (!fs::exists(dir / file)) {
        Fail(dir.string() + ": " + file + " is missing, though its journal records it");
      }
    }
    scene.input = index;
    scene.offset = offset;
    input.scenes.push_back(std::move(scene));
  });
  input.task = ReadTask(dir);
  return input;
}

std::string SceneText(const Recorded& scene) {
  return "scene " + std::to_string(scene.generator_id) + "/" + std::to_string(scene.seq);
}

// every task 0..T-1 of one job exactly once, each holding its own seqs
void CheckTasks(const std::vector<Input>& inputs) {
  const size_t with_task = static_cast<size_t>(std::count_if(
      inputs.begin(), inputs.end(), [](const Input& input) { return input.task.has_value(); }));
  if (with_task == 0) return;
  if (with_task != inputs.size()) {
    for (const Input& input : inputs) {
      if (!input.task) Fail(input.dir.string() + ": no task.json, unlike the other inputs");
    }
  }
  const TaskShard& job = *inputs.front().task;
  std::map<int64_t, const Input*> tasks;
  for (const Input& input : inputs) {
    const TaskShard& task = *input.task;
    if (task.tasks != job.tasks || task.total != job.total ||
        task.generator_id != job.generator_id) {
      Fail(input.dir.string() + ": task " + std::to_string(task.task) + " of " +
           std::to_string(task.tasks) + " (" + std::to_string(task.total) +
           " scenes) is of another job than " + inputs.front().dir.string() + " (" +
           std::to_string(job.tasks) + " tasks, " + std::to_string(job.total) + " scenes)");
    }
    const auto [other, added] = tasks.emplace(task.task, &input);
    if (!added) {
      Fail(input.dir.string() + ": task " + std::to_string(task.task) + " of " +
           std::to_string(task.tasks) + " is given twice (also " + other->second->dir.string() +
           ")");
    }
    if (static_cast<int64_t>(input.scenes.size()) != task.count) {
      Fail(input.dir.string() + ": task " + std::to_string(task.task) + " holds " +
           std::to_string(input.scenes.size()) + " scenes, its task.json says " +
           std::to_string(task.count));
    }
    for (const Recorded& scene : input.scenes) {
      if (scene.generator_id != task.generator_id || scene.seq < task.first_seq ||
          scene.seq >= task.first_seq + task.count) {
        Fail(input.dir.string() + ": " + SceneText(scene) + " is not one of task " +
             std::to_string(task.task) + "'s seqs");
      }
    }
  }
  for (int64_t task = 0; task < job.tasks; ++task) {
    if (tasks.count(task) == 0) {
      char folder[32];
      std::snprintf(folder, sizeof folder, "task-%05lld", static_cast<long long>(task));
      Fail("task " + std::to_string(task) + " of " + std::to_string(job.tasks) + " (seqs " +
           std::to_string(task * job.total / job.tasks) + ".." +
           std::to_string((task + 1) * job.total / job.tasks - 1) +
           ") is missing: no input is its shard " + folder + "; run it again (tools/task --task " +
           std::to_string(task) + ")");
    }
  }
}

// one format and labelling, one run, no scene twice; the scenes in (generator id, seq) order
std::vector<const Recorded*> CheckInputs(const std::vector<Input>& inputs) {
  const Input& first = inputs.front();
  std::string run;
  const Input* run_input = nullptr;
  std::map<std::pair<int32_t, int64_t>, const Recorded*> scenes;
  CheckTasks(inputs);
  for (const Input& input : inputs) {
    if (input.format != first.format) {
      Fail(input.dir.string() + ": a " + (input.format == Format::kCoco ? "COCO" : "BOP") +
           " dataset, " + first.dir.string() + " is " +
           (first.format == Format::kCoco ? "COCO" : "BOP"));
    }
    if (!input.scenes.empty() && !first.scenes.empty() && input.options != first.options) {
      Fail(input.dir.string() + ": written with " + input.options + ", " + first.dir.string() +
           " with " + first.options);
    }
    for (const Recorded& scene : input.scenes) {
      if (run.empty() && !scene.run.empty()) {
        run = scene.run;
        run_input = &input;
      }
      if (!scene.run.empty() && !SameRun(scene.run, run)) {
        Fail(input.dir.string() + ": " + SceneText(scene) + " is of another run (" + scene.run +
             ") than " + run_input->dir.string() + " (" + run + ")");
      }
      const auto [other, added] =
          scenes.emplace(std::make_pair(scene.generator_id, scene.seq), &scene);
      if (!added) {
        Fail(input.dir.string() + ": " + SceneText(scene) + " is also in " +
             inputs[other->second->input].dir.string() +
             " (an input given twice, or shards that "
             "overlap)");
      }
    }
  }
  std::vector<const Recorded*> ordered;
  for (const auto& [key, scene] : scenes) ordered.push_back(scene);
  return ordered;
}

// `from` at `to`: a hard link, or a copy where links cannot go (another file system)
void Place(const fs::path& from, const fs::path& to) {
  fs::create_directories(to.parent_path());
  std::error_code error;
  fs::create_hard_link(from, to, error);
  if (!error) return;
  fs::copy_file(from, to, error);
  if (error) Fail("cannot copy " + from.string() + " to " + to.string() + ": " + error.message());
}

// the dataset in `dir` from the records: the files, the joined journal, then the writer's own
// files from it
int64_t WriteMerged(const std::vector<Input>& inputs, const std::vector<const Recorded*>& scenes,
                    const fs::path& dir, int shards) {
  const Input& first = inputs.front();
  fs::create_directories(dir);
  // the journal: each scene's line (with its '\n') read through the input's locked journal,
  // in (generator id, seq) order
  WriteFileWhole(dir / JournalName(first.format), [&](OutputFile& out) {
    for (const Recorded* scene : scenes) {
      const Input& input = inputs[scene->input];
      for (const std::string& file : scene->files) Place(input.dir / file, dir / file);
      out.Write(ReadAt(*input.lock, scene->offset, scene->length + 1,
                       (input.dir / JournalName(input.format)).string()));
    }
  });
  if (first.format == Format::kCoco) {
    CocoWriterOptions options;
    options.resume = true;
    options.shard_images = shards;
    for (const Input& input : inputs) {
      if (input.scenes.empty()) continue;
      const json& coco = input.coco_options;
      if (!coco.at("min_visib_fract").is_null()) {
        options.min_visib_fract = coco.at("min_visib_fract").get<double>();
      }
      options.polygons = coco.at("polygons").get<bool>();
      break;
    }
    CocoWriter writer(dir.string(), options);
    writer.Finish();
    return writer.num_images();
  }
  // BOP: the models (the same in every input) and the camera of the first scene
  const Input& lowest = scenes.empty() ? first : inputs[scenes.front()->input];
  for (const Input& input : inputs) {
    if (!fs::exists(input.dir / "models")) continue;
    for (const auto& entry : fs::directory_iterator(input.dir / "models")) {
      const fs::path to = dir / "models" / entry.path().filename();
      if (!fs::exists(to)) {
        Place(entry.path(), to);
      } else if (ReadWholeFile(to.string()) != ReadWholeFile(entry.path().string())) {
        Fail(entry.path().string() + " differs from the same model of another input");
      }
    }
  }
  if (fs::exists(lowest.dir / "camera.json"))
    Place(lowest.dir / "camera.json", dir / "camera.json");
  BopWriterOptions options;
  options.resume = true;
  options.shard_images = shards;
  if (!scenes.empty()) options.split = first.options.substr(std::string("split ").size());
  BopWriter writer(dir.string(), options);
  writer.Finish();
  return writer.num_images();
}

int Run(int argc, char** argv) {
  std::string out;
  int shards = 0;
  std::vector<std::string> paths;
  FlagParser parser("stackgen-merge");
  parser.String("--out", &out, "a folder");
  parser.Require("--out");
  parser.Int("--shards", &shards, 1, 1000);
  parser.Positional(&paths, "INPUT", 1, 1000000);
  parser.ParseOrExit(argc, argv, [] { std::printf("%s", kUsage); });

  const fs::path target = fs::path(out).lexically_normal();
  if (fs::exists(target) && !(fs::is_directory(target) && fs::is_empty(target))) {
    Fail(out + " exists and is not an empty folder: merge into a new one");
  }
  std::vector<Input> inputs;
  std::map<fs::path, std::string> seen;
  for (size_t k = 0; k < paths.size(); ++k) {
    const auto [other, added] = seen.emplace(fs::weakly_canonical(paths[k]), paths[k]);
    if (!added) Fail(paths[k] + ": given twice (also as " + other->second + ")");
    inputs.push_back(LoadInput(paths[k], k));
  }
  const std::vector<const Recorded*> scenes = CheckInputs(inputs);
  for (const Input& input : inputs) {
    if (fs::weakly_canonical(input.dir) == fs::weakly_canonical(target)) {
      Fail(input.dir.string() + " is the output folder too");
    }
  }

  // written beside the target and renamed when whole: a merge killed half way leaves no
  // dataset at DIR, and its leftover DIR.merging is removed by the next merge
  const fs::path staging = target.string() + ".merging";
  fs::remove_all(staging);
  const int64_t stored = WriteMerged(inputs, scenes, staging, shards);
  if (fs::exists(target)) fs::remove(target);
  fs::rename(staging, target);
  std::printf("stackgen-merge: %lld scenes of %zu inputs -> %s (%s)\n",
              static_cast<long long>(stored), inputs.size(), out.c_str(),
              inputs.front().format == Format::kCoco ? "COCO" : "BOP");
  return 0;
}

}  // namespace
}  // namespace stackgen

int main(int argc, char** argv) {
  try {
    return stackgen::Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen-merge: error: %s\n", error.what());
    return 1;
  }
}
