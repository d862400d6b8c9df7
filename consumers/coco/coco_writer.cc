#include "consumers/coco/coco_writer.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <limits>
#include <set>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/bounded_decode.h"
#include "bus/scene_contract.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// id layout: image id = generator_id * 1e9 + seq + 1, annotation id = image id * 1000 +
// instance_id; these bounds keep both unique and inside int64
// (kMaxGeneratorId and kMaxSeq of bus/scene_contract.h keep them there)
constexpr int64_t kSeqsPerGenerator = 1000000000;
static_assert(kMaxSeq < kSeqsPerGenerator - 1, "a seq's image id would reach the next generator");
constexpr int32_t kMaxCocoInstanceId = 999;

constexpr const char* kAnnotationsFile = "annotations.json";
constexpr const char* kJournalFile = "annotations.journal";
constexpr const char* kImagesFolder = "images";
constexpr std::string_view kTemporarySuffix = ".tmp";

// a journal line: {"image":IMAGE,"annotations":[ANNOTATIONS],"scene":SCENE}\n (see the header)
constexpr int kJournalVersion = 1;
constexpr std::string_view kImagePrefix = "{\"image\":";
constexpr std::string_view kAnnotationsPrefix = ",\"annotations\":[";
constexpr std::string_view kScenePrefix = "],\"scene\":";

// the scene's name in error messages: "scene <generator_id>/<seq>"
std::string SceneName(const stackgen::scene& scene) {
  return "scene " + std::to_string(scene.header.generator_id) + "/" +
         std::to_string(scene.header.seq);
}

[[noreturn]] void Fail(const std::string& scene_name, const std::string& text) {
  throw InvalidSceneError(scene_name + ": " + text);
}

// whether `text` is valid UTF-8 (JSON text must be)
bool IsUtf8(const std::string& text) {
  try {
    json(text).dump();
    return true;
  } catch (const json::type_error&) {
    return false;
  }
}

// images/<generator_id>_<seq:06>.png, .jpg for a JPEG scene
std::string ImageFileName(const stackgen::scene& scene) {
  char seq[32];
  std::snprintf(seq, sizeof(seq), "%06lld", static_cast<long long>(scene.header.seq));
  const bool jpeg = scene.color.encoding == stackgen::image::ENCODING_JPEG;
  return std::to_string(scene.header.generator_id) + "_" + seq + (jpeg ? ".jpg" : ".png");
}

// the size of the file `path` in bytes, -1 if there is none
int64_t FileSize(const std::string& path) {
  struct stat status {};
  if (stat(path.c_str(), &status) == 0) return static_cast<int64_t>(status.st_size);
  if (errno == ENOENT) return -1;
  throw std::runtime_error("cannot read " + path + ": " + std::strerror(errno));
}

// "<what> <path>: <the system's reason>"
std::runtime_error SystemError(const std::string& what, const std::string& path, int error_number) {
  return std::runtime_error(what + " " + path + ": " + std::strerror(error_number));
}

// closes a file descriptor at scope exit
class ScopedFd {
 public:
  explicit ScopedFd(int fd) : fd_(fd) {}
  ~ScopedFd() {
    if (fd_ >= 0) close(fd_);
  }
  ScopedFd(const ScopedFd&) = delete;
  ScopedFd& operator=(const ScopedFd&) = delete;
  int get() const { return fd_; }
  // closes now; the errno of a failed close, else 0
  int Close() {
    const int result = close(fd_);
    fd_ = -1;
    return result == 0 ? 0 : errno;
  }

 private:
  int fd_;
};

// writes all `size` bytes at the file position (offset < 0) or at `offset`; the errno of the
// first failure, else 0
int WriteAll(int fd, const char* bytes, size_t size, int64_t offset = -1) {
  while (size > 0) {
    const ssize_t written = offset < 0 ? write(fd, bytes, size) : pwrite(fd, bytes, size, offset);
    if (written < 0 && errno == EINTR) continue;
    if (written < 0) return errno;
    if (written == 0) return EIO;  // no progress: never loop forever
    bytes += written;
    size -= static_cast<size_t>(written);
    if (offset >= 0) offset += written;
  }
  return 0;
}

// `length` bytes of `fd` (the file `path`) at `offset`
std::string ReadAt(int fd, uint64_t offset, uint64_t length, const std::string& path) {
  std::string bytes(length, '\0');
  uint64_t done = 0;
  while (done < length) {
    const ssize_t got =
        pread(fd, bytes.data() + done, length - done, static_cast<off_t>(offset + done));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) {
      throw std::runtime_error("cannot read " + path + " at byte " + std::to_string(offset + done) +
                               ": " + (got < 0 ? std::strerror(errno) : "the file ends early"));
    }
    done += static_cast<uint64_t>(got);
  }
  return bytes;
}

// makes the entries of folder `path` (files created, renamed or removed in it) durable
void SyncFolder(const fs::path& path) {
  const std::string name = path.empty() ? "." : path.string();
  ScopedFd folder(open(name.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (folder.get() < 0) throw SystemError("cannot open", name, errno);
  // a file system that cannot sync a folder says EINVAL; it has nothing more to do
  if (fsync(folder.get()) != 0 && errno != EINVAL) throw SystemError("cannot sync", name, errno);
}

// writes `size` bytes to `path` through `path`.tmp, with `sync` synced to disk before the rename
// and the folder synced after it; on failure removes what it wrote and throws naming the file and
// reason
void WriteFileAtomically(const fs::path& path, const char* bytes, size_t size, bool sync) {
  const std::string temporary = path.string() + ".tmp";
  // write and sync the temporary file, or remove it
  {
    ScopedFd file(open(temporary.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
    if (file.get() < 0) throw SystemError("cannot create", temporary, errno);
    int error = WriteAll(file.get(), bytes, size);
    if (error == 0 && sync && fsync(file.get()) != 0) error = errno;
    const int close_error = file.Close();
    if (error == 0) error = close_error;
    if (error != 0) {
      unlink(temporary.c_str());
      throw SystemError("cannot write", temporary, error);
    }
  }
  // move it into place; the rename is durable once the folder is synced
  if (rename(temporary.c_str(), path.c_str()) != 0) {
    const int error = errno;
    unlink(temporary.c_str());
    throw std::runtime_error("cannot rename " + temporary + " to " + path.string() + ": " +
                             std::strerror(error));
  }
  if (!sync) return;
  try {
    SyncFolder(path.parent_path());
  } catch (const std::runtime_error&) {
    unlink(path.c_str());
    throw;
  }
}

// a file written through a buffer; every failure throws naming the file and the reason
class OutputFile {
 public:
  explicit OutputFile(std::string path) : path_(std::move(path)) {
    fd_ = open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd_ < 0) throw SystemError("cannot create", path_, errno);
  }
  ~OutputFile() {
    if (fd_ >= 0) close(fd_);
  }
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  void Write(std::string_view text) {
    buffer_.append(text);
    if (buffer_.size() >= kFlushBytes) Flush();
  }
  // writes what is buffered, syncs the file to disk and closes it
  void Close() {
    Flush();
    if (fsync(fd_) != 0) throw SystemError("cannot write", path_, errno);
    const int result = close(fd_);
    fd_ = -1;
    if (result != 0) throw SystemError("cannot write", path_, errno);
  }

 private:
  static constexpr size_t kFlushBytes = 1 << 20;

  void Flush() {
    const int error = WriteAll(fd_, buffer_.data(), buffer_.size());
    if (error != 0) throw SystemError("cannot write", path_, error);
    buffer_.clear();
  }

  std::string path_;
  int fd_ = -1;
  std::string buffer_;
};

json PoseJson(const stackgen::pose& pose) {
  return {{"translation_mm", std::vector<double>(pose.translation_mm, pose.translation_mm + 3)},
          {"rotation", std::vector<double>(pose.rotation, pose.rotation + 9)},
          {"quaternion_wxyz", std::vector<double>(pose.quaternion_wxyz, pose.quaternion_wxyz + 4)}};
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

// writes `records` (JSON values separated by ',' as in a journal line) to `out` separated by
// ",\n" instead, as annotations.json lists them
void WriteOnePerLine(std::string_view records, OutputFile& out) {
  int depth = 0;
  bool in_string = false, escaped = false;
  size_t start = 0;
  for (size_t i = 0; i < records.size(); ++i) {
    const char c = records[i];
    // inside a string only its end counts
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    // outside: nesting, and the commas between top-level values
    if (c == '"') {
      in_string = true;
    } else if (c == '{' || c == '[') {
      ++depth;
    } else if (c == '}' || c == ']') {
      --depth;
    } else if (c == ',' && depth == 0) {
      out.Write(records.substr(start, i + 1 - start));
      out.Write("\n");
      start = i + 1;
    }
  }
  out.Write(records.substr(start));
}

// whether `name` looks like an image file this writer writes: <digits>_<6+ digits>.png|.jpg
bool IsImageFileName(const std::string& name) {
  const size_t underscore = name.find('_');
  const size_t dot = name.rfind('.');
  if (underscore == std::string::npos || dot == std::string::npos || underscore == 0 ||
      dot < underscore + 7) {
    return false;
  }
  const auto digits = [&](size_t begin, size_t end) {
    return std::all_of(name.begin() + begin, name.begin() + end,
                       [](char c) { return c >= '0' && c <= '9'; });
  };
  const std::string extension = name.substr(dot);
  return digits(0, underscore) && digits(underscore + 1, dot) &&
         (extension == ".png" || extension == ".jpg");
}

}  // namespace

CocoWriter::CocoWriter(const std::string& dir, const CocoWriterOptions& options)
    : dir_(dir), options_(options) {
  if (options_.min_visib_fract &&
      !(*options_.min_visib_fract >= 0.0 && *options_.min_visib_fract <= 1.0)) {
    throw std::runtime_error("min_visib_fract " + std::to_string(*options_.min_visib_fract) +
                             " outside [0, 1]");
  }
  const fs::path folder(dir_);
  const std::string annotations = (folder / kAnnotationsFile).string();
  journal_path_ = (folder / kJournalFile).string();

  // never overwrite a dataset; resume one only from its journal
  const int64_t annotations_size = FileSize(annotations);
  const int64_t journal_size = FileSize(journal_path_);
  if (!options_.resume) {
    if (annotations_size > 0 && journal_size >= 0) {
      throw std::runtime_error(annotations +
                               " already exists; will not overwrite it (use --resume to extend "
                               "this dataset, or choose another output folder)");
    }
    if (annotations_size > 0) {
      throw std::runtime_error(annotations + " already exists and there is no " + kJournalFile +
                               " to resume it from; will not overwrite it (choose another output "
                               "folder or remove it)");
    }
    if (journal_size > 0) {
      throw std::runtime_error(journal_path_ +
                               " already exists (a dataset was started here); will not "
                               "overwrite it (use --resume to continue it, or choose another "
                               "output folder)");
    }
  } else if (annotations_size > 0 && journal_size < 0) {
    throw std::runtime_error("cannot resume " + annotations + " without its journal: " +
                             journal_path_ + " is missing (choose another output folder)");
  }

  // the folders, each new one made durable in its parent
  const fs::path images = folder / kImagesFolder;
  std::vector<fs::path> created;
  std::error_code error;
  for (fs::path path = images;
       !path.empty() && path != path.parent_path() && !fs::exists(path, error);
       path = path.parent_path()) {
    created.push_back(path);
  }
  fs::create_directories(images, error);
  if (error) throw std::runtime_error("cannot create " + images.string() + ": " + error.message());
  // a writer that cannot open leaves nothing it made behind: the journal it created, empty, and
  // the folders it created, empty
  const bool journal_existed = FileSize(journal_path_) >= 0;
  const auto remove_created = [&] {
    if (!journal_existed && FileSize(journal_path_) == 0) unlink(journal_path_.c_str());
    std::error_code ignored;
    for (const fs::path& path : created) fs::remove(path, ignored);  // only if empty
  };
  try {
    for (const fs::path& path : created) SyncFolder(path.parent_path());
  } catch (...) {
    remove_created();
    throw;
  }

  // the journal, locked against a second writer
  journal_fd_ = open(journal_path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (journal_fd_ < 0) {
    const int open_error = errno;
    remove_created();
    throw SystemError("cannot open", journal_path_, open_error);
  }
  try {
    if (flock(journal_fd_, LOCK_EX | LOCK_NB) != 0) {
      if (errno == EWOULDBLOCK) {
        throw std::runtime_error(journal_path_ +
                                 " is in use by another writer (one writer per dataset folder)");
      }
      throw SystemError("cannot lock", journal_path_, errno);
    }
    // reload it, or make sure it is still empty now that it is ours
    std::set<std::string> journaled_images;
    if (options_.resume) {
      journaled_images = LoadJournal();
    } else if (FileSize(journal_path_) > 0) {
      throw std::runtime_error(journal_path_ +
                               " already exists (a dataset was started here); will not "
                               "overwrite it (use --resume to continue it, or choose another "
                               "output folder)");
    }
    // leftovers of an Add or a Finish that never completed
    CleanImagesFolder(journaled_images);
    const std::string annotations_temporary = annotations + std::string(kTemporarySuffix);
    if (unlink(annotations_temporary.c_str()) != 0 && errno != ENOENT) {
      throw SystemError("cannot remove", annotations_temporary, errno);
    }
    SyncFolder(folder);
  } catch (...) {
    close(journal_fd_);
    journal_fd_ = -1;
    remove_created();
    throw;
  }
}

CocoWriter::~CocoWriter() {
  // the journal stays: it is the dataset's durable record
  if (journal_fd_ >= 0) close(journal_fd_);
}

std::set<std::string> CocoWriter::LoadJournal() {
  std::set<std::string> journaled_images;
  // line by line; a last line without its '\n' is a torn write
  std::vector<char> buffer(1 << 20);
  std::string line;
  uint64_t read_offset = 0, line_offset = 0;
  int64_t line_number = 0;
  while (true) {
    const ssize_t got =
        pread(journal_fd_, buffer.data(), buffer.size(), static_cast<off_t>(read_offset));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) throw SystemError("cannot read", journal_path_, errno);
    if (got == 0) break;
    read_offset += static_cast<uint64_t>(got);
    const char* begin = buffer.data();
    const char* const end = begin + got;
    while (begin < end) {
      const char* const newline =
          static_cast<const char*>(std::memchr(begin, '\n', static_cast<size_t>(end - begin)));
      if (newline == nullptr) {
        line.append(begin, end);
        break;
      }
      line.append(begin, newline);
      LoadJournalLine(line, line_offset, ++line_number, &journaled_images);
      line_offset += line.size() + 1;
      line.clear();
      begin = newline + 1;
    }
  }

  // cut the torn line off, durably, so the next line starts clean
  if (!line.empty()) {
    if (ftruncate(journal_fd_, static_cast<off_t>(line_offset)) != 0 || fsync(journal_fd_) != 0) {
      throw SystemError("cannot cut the torn last line off", journal_path_, errno);
    }
    truncated_journal_bytes_ = static_cast<int64_t>(line.size());
  }
  journal_size_ = line_offset;
  resumed_scenes_ = static_cast<int64_t>(index_.size());
  return journaled_images;
}

void CocoWriter::LoadJournalLine(const std::string& line, uint64_t offset, int64_t line_number,
                                 std::set<std::string>* journaled_images) {
  const std::string where = journal_path_ + " line " + std::to_string(line_number) + " (byte " +
                            std::to_string(offset) + ")";
  const auto corrupt = [&where](const std::string& text) {
    return std::runtime_error(where + ": " + text);
  };
  JournalEntry entry;
  SceneCounts counts;
  std::map<int32_t, std::string> scene_categories;
  std::string file_name;
  try {
    const json record = json::parse(line);
    if (!record.is_object() || !record.contains("image") || !record.contains("annotations") ||
        !record.contains("scene")) {
      throw corrupt("not a stackgen-coco journal line (image, annotations and scene expected)");
    }
    const json& scene = record["scene"];
    if (scene.at("journal_version") != kJournalVersion) {
      throw corrupt("journal_version " + scene["journal_version"].dump() + " is not " +
                    std::to_string(kJournalVersion));
    }

    // the scene, once, and its image record
    const int64_t generator_id = scene.at("generator_id").get<int64_t>();
    const int64_t seq = scene.at("seq").get<int64_t>();
    const std::string scene_name =
        "scene " + std::to_string(generator_id) + "/" + std::to_string(seq);
    if (generator_id < 0 || generator_id > kMaxGeneratorId ||
        !SceneIdsInRange(static_cast<int32_t>(generator_id), seq)) {
      throw corrupt(scene_name + " is outside the id layout");
    }
    entry.generator_id = static_cast<int32_t>(generator_id);
    entry.seq = seq;
    entry.seed = record.at("image").at("stackgen").at("seed").get<int64_t>();
    if (scene.contains("run")) {
      if (!scene["run"].is_string()) throw corrupt("scene.run is not a string");
      runs_[entry.generator_id] = scene["run"].get<std::string>();
    }
    const int64_t image_id = ImageId(entry.generator_id, seq);
    if (index_.count(image_id) != 0) throw corrupt(scene_name + " is recorded twice");
    const json& image = record["image"];
    if (image.at("id") != image_id) {
      throw corrupt("image.id " + image["id"].dump() + " is not " + std::to_string(image_id) +
                    ", the id of " + scene_name);
    }
    file_name = image.at("file_name").get<std::string>();
    if (!IsImageFileName(file_name)) {
      throw corrupt("image.file_name \"" + file_name + "\" is not a name this writer gives");
    }

    // where the records lie: {"image":IMAGE,"annotations":[ANNOTATIONS],"scene":...
    const uint64_t image_length = scene.at("image_length").get<uint64_t>();
    const uint64_t annotations_length = scene.at("annotations_length").get<uint64_t>();
    const uint64_t annotations_start =
        kImagePrefix.size() + image_length + kAnnotationsPrefix.size();
    if (image_length > line.size() || annotations_length > line.size() ||
        annotations_start + annotations_length + kScenePrefix.size() > line.size() ||
        line.compare(0, kImagePrefix.size(), kImagePrefix) != 0 ||
        line.compare(kImagePrefix.size() + image_length, kAnnotationsPrefix.size(),
                     kAnnotationsPrefix) != 0 ||
        line.compare(annotations_start + annotations_length, kScenePrefix.size(), kScenePrefix) !=
            0 ||
        json::parse(line.substr(kImagePrefix.size(), image_length)) != image) {
      throw corrupt("image_length " + std::to_string(image_length) + " or annotations_length " +
                    std::to_string(annotations_length) + " does not match the line");
    }
    entry.image_offset = offset + kImagePrefix.size();
    entry.image_length = image_length;
    entry.annotations_offset = offset + annotations_start;
    entry.annotations_length = annotations_length;

    // its counts
    counts.annotations = scene.at("num_annotations").get<int64_t>();
    counts.crowd = scene.at("num_crowd").get<int64_t>();
    counts.dropped = scene.at("num_dropped").get<int64_t>();
    const json& annotations = record["annotations"];
    if (counts.annotations < 0 || counts.crowd < 0 || counts.dropped < 0 ||
        !annotations.is_array() ||
        annotations.size() != static_cast<uint64_t>(counts.annotations + counts.crowd)) {
      throw corrupt("num_annotations " + std::to_string(counts.annotations) + " + num_crowd " +
                    std::to_string(counts.crowd) + " does not match the " +
                    std::to_string(annotations.size()) + " annotation records");
    }

    // written with the same filter as this writer's
    const json& min_visib_fract = scene.at("min_visib_fract");
    const json own = options_.min_visib_fract ? json(*options_.min_visib_fract) : json(nullptr);
    if (min_visib_fract != own) {
      throw corrupt("written with min_visib_fract " + min_visib_fract.dump() +
                    ", this writer has " + own.dump() + " (resume with the same min_visib_fract)");
    }

    // categories agree with every other line's
    for (const json& category : scene.at("categories")) {
      const int32_t class_id = category.at(0).get<int32_t>();
      const std::string class_name = category.at(1).get<std::string>();
      const auto known = categories_.find(class_id);
      if (class_id < 1 || class_name.empty() ||
          (known != categories_.end() && known->second != class_name)) {
        throw corrupt("category " + category.dump() + " is not valid or differs from an earlier " +
                      "line's" +
                      (known != categories_.end() ? " \"" + known->second + "\"" : std::string()));
      }
      scene_categories.emplace(class_id, class_name);
    }
  } catch (const json::parse_error& error) {
    throw corrupt("not a journal record: invalid JSON at byte " + std::to_string(error.byte) +
                  " of the line (the journal is damaged; annotations.journal lines are written "
                  "only by stackgen-coco)");
  } catch (const json::exception& error) {
    throw corrupt(error.what());
  }

  // a valid line: index it
  Index(entry, counts);
  categories_.insert(scene_categories.begin(), scene_categories.end());
  journaled_images->insert(file_name);
}

void CocoWriter::CleanImagesFolder(const std::set<std::string>& journaled_images) const {
  const fs::path images = fs::path(dir_) / kImagesFolder;
  size_t present = 0;
  std::error_code error;
  for (fs::directory_iterator it(images, error), end; !error && it != end; it.increment(error)) {
    const std::string name = it->path().filename().string();
    if (journaled_images.count(name) != 0) {
      ++present;
      continue;
    }
    // temporary files, and with resume image files no journal line names (an Add that never
    // completed wrote them)
    std::error_code type_error;
    if (!it->is_regular_file(type_error)) continue;
    const bool temporary = name.size() > kTemporarySuffix.size() &&
                           name.compare(name.size() - kTemporarySuffix.size(),
                                        kTemporarySuffix.size(), kTemporarySuffix) == 0;
    if ((temporary || (options_.resume && IsImageFileName(name))) &&
        unlink(it->path().c_str()) != 0) {
      throw SystemError("cannot remove", it->path().string(), errno);
    }
  }
  if (error) throw std::runtime_error("cannot read " + images.string() + ": " + error.message());

  // every journaled scene has its image
  if (present < journaled_images.size()) {
    for (const std::string& name : journaled_images) {
      if (!fs::exists(images / name, error)) {
        throw std::runtime_error((images / name).string() + " is missing, though " + journal_path_ +
                                 " records it (the dataset is damaged)");
      }
    }
  }
}

void CocoWriter::Index(const JournalEntry& entry, const SceneCounts& counts) {
  index_.emplace(ImageId(entry.generator_id, entry.seq), entry);
  num_annotations_ += counts.annotations;
  num_crowd_ += counts.crowd;
  num_dropped_ += counts.dropped;
  // StoredThrough moves on while the next seq is there
  int64_t& through = stored_through_.emplace(entry.generator_id, -1).first->second;
  while (Has(entry.generator_id, through + 1)) ++through;
}

int64_t CocoWriter::ImageId(int32_t generator_id, int64_t seq) {
  return int64_t{generator_id} * kSeqsPerGenerator + seq + 1;
}

int64_t CocoWriter::AnnotationId(int64_t image_id, int32_t instance_id) {
  return image_id * 1000 + instance_id;
}

void CocoWriter::Validate(const stackgen::scene& scene) const {
  const std::string name = SceneName(scene);
  // the contract every consumer checks (bus/scene_contract.h)
  std::string why;
  if (!CheckScene(scene, &why)) Fail(name, why);

  // a PNG or JPEG file is stored as it came: it must decode, whole (libpng checks every chunk's
  // CRC and zlib the data's checksum, so a flipped bit or a cut shows; a JPEG must also end
  // with its end-of-image marker, as libjpeg fills a cut one with grey)
  const stackgen::image& color = scene.color;
  const int channels = color.pixel_format == stackgen::image::PIXEL_RGB8 ? 3 : 1;
  if (color.encoding != stackgen::image::ENCODING_RAW) {
    const bool png = color.encoding == stackgen::image::ENCODING_PNG;
    const bool jpeg_ends = color.data.size() >= 2 && color.data[color.data.size() - 2] == 0xff &&
                           color.data.back() == 0xd9;
    const cv::Mat decoded =
        png || jpeg_ends ? cv::imdecode(color.data, cv::IMREAD_UNCHANGED) : cv::Mat();
    if (decoded.empty() || decoded.cols != color.width || decoded.rows != color.height ||
        decoded.depth() != CV_8U || decoded.channels() != channels) {
      Fail(name, std::string("color.data does not decode as a whole ") + (png ? "PNG" : "JPEG") +
                     " image of " + std::to_string(color.width) + " x " +
                     std::to_string(color.height) + " x " + std::to_string(channels) +
                     " bytes (damaged or cut short)");
    }
  }

  // what COCO and this dataset need beyond it: annotation ids (image id * 1000 + instance_id),
  // JSON text, one name per class_id across the dataset
  std::map<int32_t, std::string> scene_categories;
  for (size_t i = 0; i < scene.instances.size(); ++i) {
    const stackgen::instance& instance = scene.instances[i];
    const std::string field = "instances[" + std::to_string(i) + "]";
    if (instance.instance_id > kMaxCocoInstanceId) {
      Fail(name, field + ".instance_id " + std::to_string(instance.instance_id) + " outside 1.." +
                     std::to_string(kMaxCocoInstanceId) +
                     " (annotation id = image id * 1000 + instance_id)");
    }
    if (!IsUtf8(instance.class_name)) Fail(name, field + ".class_name is not valid UTF-8");
    // the name stored (or staged) before for this class
    const std::string* known = nullptr;
    for (const auto* seen : {&categories_, &staged_categories_}) {
      const auto found = seen->find(instance.class_id);
      if (known == nullptr && found != seen->end()) known = &found->second;
    }
    const auto in_scene = scene_categories.emplace(instance.class_id, instance.class_name).first;
    if ((known != nullptr && *known != instance.class_name) ||
        in_scene->second != instance.class_name) {
      Fail(name, field + ".class_name \"" + instance.class_name + "\" differs from \"" +
                     (known != nullptr ? *known : in_scene->second) +
                     "\" seen before for class_id " + std::to_string(instance.class_id));
    }
  }
}

void CocoWriter::WriteImageFile(const stackgen::scene& scene, const std::string& path,
                                bool sync) const {
  const stackgen::image& color = scene.color;
  if (color.encoding != stackgen::image::ENCODING_RAW) {
    // PNG and JPEG: the bytes as they came
    WriteFileAtomically(path, reinterpret_cast<const char*>(color.data.data()), color.data.size(),
                        sync);
    return;
  }
  // RAW: encode to PNG (OpenCV wants BGR order)
  const bool rgb = color.pixel_format == stackgen::image::PIXEL_RGB8;
  const cv::Mat pixels(color.height, color.width, rgb ? CV_8UC3 : CV_8UC1,
                       const_cast<uint8_t*>(color.data.data()));
  cv::Mat to_encode = pixels;
  if (rgb) cv::cvtColor(pixels, to_encode, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> png;
  if (!cv::imencode(".png", to_encode, png)) {
    throw std::runtime_error("cannot encode " + path + " as PNG");
  }
  WriteFileAtomically(path, reinterpret_cast<const char*>(png.data()), png.size(), sync);
}

void CocoWriter::AppendToJournal(const std::string& line) {
  if (journal_broken_) {
    throw std::runtime_error("cannot write " + journal_path_ +
                             ": an earlier failed write could not be cut back (resume the "
                             "dataset to repair it)");
  }
  // write and sync the line, or cut the journal back to its last complete line
  int error = WriteAll(journal_fd_, line.data(), line.size(), static_cast<int64_t>(journal_size_));
  if (error == 0 && fsync(journal_fd_) != 0) error = errno;
  if (error != 0) {
    if (ftruncate(journal_fd_, static_cast<off_t>(journal_size_)) != 0 || fsync(journal_fd_) != 0) {
      journal_broken_ = true;
    }
    throw SystemError("cannot write", journal_path_, error);
  }
  journal_size_ += line.size();
}

bool CocoWriter::Add(const stackgen::scene& scene) {
  // store each (generator_id, seq) once; the same ids with another seed come from another run
  const std::string scene_name = SceneName(scene);
  if (!SceneIdsInRange(scene.header.generator_id, scene.header.seq)) {
    Fail(scene_name, "generator_id or seq outside the id layout (generator_id 0.." +
                         std::to_string(kMaxGeneratorId) + ", seq 0.." + std::to_string(kMaxSeq) +
                         ")");
  }
  const int64_t image_id = ImageId(scene.header.generator_id, scene.header.seq);
  const auto stored = index_.find(image_id);
  if (stored != index_.end()) {
    if (stored->second.seed != scene.header.seed) {
      Fail(scene_name, "header.seed " + std::to_string(scene.header.seed) +
                           " differs from the stored scene's " +
                           std::to_string(stored->second.seed) +
                           ": another run with the same --generator-id (give each run its own "
                           "id, or write it to another --out)");
    }
    return false;
  }
  const auto staged = staged_seeds_.find(image_id);
  if (staged != staged_seeds_.end()) {
    if (staged->second != scene.header.seed) {
      Fail(scene_name, "header.seed " + std::to_string(scene.header.seed) +
                           " differs from the stored scene's " + std::to_string(staged->second) +
                           ": another run with the same --generator-id (give each run its own "
                           "id, or write it to another --out)");
    }
    return false;
  }
  Validate(scene);

  // the image record
  const stackgen::camera_info& camera = scene.camera;
  const std::string file_name = ImageFileName(scene);
  json camera_json = {{"fx", camera.fx},
                      {"fy", camera.fy},
                      {"cx", camera.cx},
                      {"cy", camera.cy},
                      {"world_from_camera", PoseJson(camera.world_from_camera)},
                      {"depth_scale_mm", camera.depth_scale_mm}};
  const json image = {{"id", image_id},
                      {"file_name", file_name},
                      {"width", camera.width},
                      {"height", camera.height},
                      {"stackgen",
                       {{"seq", scene.header.seq},
                        {"generator_id", scene.header.generator_id},
                        {"seed", scene.header.seed},
                        {"camera", std::move(camera_json)}}}};

  // the annotation records, by instance id (= by annotation id)
  std::vector<const stackgen::instance*> instances;
  for (const stackgen::instance& instance : scene.instances) instances.push_back(&instance);
  std::sort(instances.begin(), instances.end(),
            [](const stackgen::instance* a, const stackgen::instance* b) {
              return a->instance_id < b->instance_id;
            });
  std::string annotations;
  int64_t scene_annotations = 0, scene_crowd = 0, scene_dropped = 0;
  for (const stackgen::instance* instance : instances) {
    // the generator's label decides: annotated -> iscrowd 0, ignored -> iscrowd 1, else nothing;
    // a min_visib_fract of our own only drops more
    const bool below_own_threshold =
        options_.min_visib_fract && instance->visib_fract < *options_.min_visib_fract;
    const bool crowd = instance->ignored;
    const bool annotation_kept = instance->annotated && !below_own_threshold;
    if (!annotation_kept && !crowd) {
      ++scene_dropped;
      continue;
    }
    const stackgen::pose& camera_from_object = instance->camera_from_object;
    const stackgen::pose& world_from_object = instance->world_from_object;
    const json annotation = {
        {"id", AnnotationId(image_id, instance->instance_id)},
        {"image_id", image_id},
        {"category_id", instance->class_id},
        {"segmentation",
         {{"size", {camera.height, camera.width}}, {"counts", instance->mask_visib_rle}}},
        {"area", instance->px_count_visib},
        {"bbox", std::vector<int32_t>(instance->bbox_visib, instance->bbox_visib + 4)},
        {"iscrowd", crowd ? 1 : 0},
        {"amodal_segmentation",
         {{"size", {camera.height, camera.width}}, {"counts", instance->mask_obj_rle}}},
        {"amodal_bbox", std::vector<int32_t>(instance->bbox_obj, instance->bbox_obj + 4)},
        {"instance_id", instance->instance_id},
        {"visib_fract", instance->visib_fract},
        {"px_count_all", instance->px_count_all},
        {"px_count_visib", instance->px_count_visib},
        {"bbox_obj", std::vector<int32_t>(instance->bbox_obj, instance->bbox_obj + 4)},
        {"posture_deg", std::vector<double>(instance->posture_deg, instance->posture_deg + 3)},
        {"resting_face", instance->resting_face},
        {"cam_R_m2c",
         std::vector<double>(camera_from_object.rotation, camera_from_object.rotation + 9)},
        {"cam_t_m2c", std::vector<double>(camera_from_object.translation_mm,
                                          camera_from_object.translation_mm + 3)},
        {"world_R_m2w",
         std::vector<double>(world_from_object.rotation, world_from_object.rotation + 9)},
        {"world_t_m2w", std::vector<double>(world_from_object.translation_mm,
                                            world_from_object.translation_mm + 3)}};
    if (!annotations.empty()) annotations += ",";
    annotations += annotation.dump();
    if (crowd) {
      ++scene_crowd;
    } else {
      ++scene_annotations;
    }
  }

  // the journal line: the records, then the scene's counts and categories
  const std::string image_text = image.dump();
  std::map<int32_t, std::string> scene_categories;
  for (const stackgen::instance& instance : scene.instances) {
    scene_categories.emplace(instance.class_id, instance.class_name);
  }
  json categories = json::array();
  for (const auto& [class_id, class_name] : scene_categories) {
    categories.push_back({class_id, class_name});
  }
  json scene_record = {{"journal_version", kJournalVersion},
                       {"generator_id", scene.header.generator_id},
                       {"seq", scene.header.seq},
                       {"num_annotations", scene_annotations},
                       {"num_crowd", scene_crowd},
                       {"num_dropped", scene_dropped},
                       {"categories", std::move(categories)},
                       {"min_visib_fract",
                        options_.min_visib_fract ? json(*options_.min_visib_fract) : json(nullptr)},
                       {"image_length", image_text.size()},
                       {"annotations_length", annotations.size()}};
  const auto run = runs_.find(scene.header.generator_id);
  if (run != runs_.end()) scene_record["run"] = run->second;
  std::string line;
  line.append(kImagePrefix).append(image_text).append(kAnnotationsPrefix).append(annotations);
  line.append(kScenePrefix).append(scene_record.dump()).append("}\n");

  // the image, then (at the commit) the line that records it; a failed line takes the image
  // with it
  const std::string image_path = (fs::path(dir_) / kImagesFolder / file_name).string();
  WriteImageFile(scene, image_path, !options_.group_commit);
  StagedScene staged_scene;
  JournalEntry& entry = staged_scene.entry;
  entry.generator_id = scene.header.generator_id;
  entry.seq = scene.header.seq;
  entry.seed = scene.header.seed;
  entry.image_offset = kImagePrefix.size();
  entry.image_length = image_text.size();
  entry.annotations_offset = entry.image_offset + image_text.size() + kAnnotationsPrefix.size();
  entry.annotations_length = annotations.size();
  staged_scene.counts = SceneCounts{scene_annotations, scene_crowd, scene_dropped};
  staged_scene.line = std::move(line);
  staged_scene.image_path = image_path;
  staged_.push_back(std::move(staged_scene));
  staged_seeds_.emplace(image_id, scene.header.seed);
  for (const auto& category : scene_categories) {
    if (categories_.count(category.first) == 0) staged_categories_.insert(category);
  }
  if (!options_.group_commit) Commit();
  return true;
}

std::vector<std::pair<int32_t, int64_t>> CocoWriter::Commit() {
  std::vector<std::pair<int32_t, int64_t>> committed;
  if (staged_.empty()) return committed;
  // drops what is staged: its image files go, nothing of it stays in the writer
  const auto drop_staged = [&] {
    if (!journal_broken_) {
      for (const StagedScene& staged : staged_) unlink(staged.image_path.c_str());
    }
    staged_.clear();
    staged_seeds_.clear();
    staged_categories_.clear();
  };
  try {
    // group commits: the image files and their names, in one sync of the file system (without,
    // each Add synced its image and the folder)
    if (options_.group_commit && syncfs(journal_fd_) != 0) {
      throw SystemError("cannot sync", (fs::path(dir_) / kImagesFolder).string(), errno);
    }
    // then the lines that record them, in one write and one sync
    std::string lines;
    for (const StagedScene& staged : staged_) lines += staged.line;
    AppendToJournal(lines);
  } catch (...) {
    drop_staged();
    throw;
  }
  // index them where their lines now lie
  uint64_t line_offset = journal_size_;
  for (const StagedScene& staged : staged_) line_offset -= staged.line.size();
  for (const StagedScene& staged : staged_) {
    JournalEntry entry = staged.entry;
    entry.image_offset += line_offset;
    entry.annotations_offset += line_offset;
    Index(entry, staged.counts);
    committed.emplace_back(entry.generator_id, entry.seq);
    line_offset += staged.line.size();
  }
  categories_.insert(staged_categories_.begin(), staged_categories_.end());
  staged_.clear();
  staged_seeds_.clear();
  staged_categories_.clear();
  return committed;
}

void CocoWriter::Finish() {
  Commit();
  const fs::path final_path = fs::path(dir_) / kAnnotationsFile;
  const std::string temporary = final_path.string() + std::string(kTemporarySuffix);
  try {
    OutputFile out(temporary);

    // info and licenses
    const std::string date = UtcNow();
    const json info = {{"description", options_.description},
                       {"version", "1.0"},
                       {"year", std::stoi(date.substr(0, 4))},
                       {"contributor", "stackgen-coco"},
                       {"url", ""},
                       {"date_created", date}};
    out.Write("{\n\"info\": " + info.dump() + ",\n\"licenses\": [],\n\"images\": [\n");

    // images, by id, as the journal holds them
    bool first = true;
    for (const auto& [image_id, entry] : index_) {
      if (!first) out.Write(",\n");
      first = false;
      out.Write(ReadAt(journal_fd_, entry.image_offset, entry.image_length, journal_path_));
    }

    // categories, by id
    out.Write("\n],\n\"categories\": [\n");
    first = true;
    for (const auto& [class_id, class_name] : categories_) {
      if (!first) out.Write(",\n");
      first = false;
      out.Write(json{{"id", class_id}, {"name", class_name}, {"supercategory", "part"}}.dump());
    }

    // annotations, by id (image ids ascending, instance ids ascending within an image), one per
    // line
    out.Write("\n],\n\"annotations\": [\n");
    first = true;
    for (const auto& [image_id, entry] : index_) {
      if (entry.annotations_length == 0) continue;
      if (!first) out.Write(",\n");
      first = false;
      WriteOnePerLine(
          ReadAt(journal_fd_, entry.annotations_offset, entry.annotations_length, journal_path_),
          out);
    }
    out.Write("\n]\n}\n");
    out.Close();
  } catch (...) {
    unlink(temporary.c_str());
    throw;
  }

  // publish it whole, durably
  if (rename(temporary.c_str(), final_path.c_str()) != 0) {
    const int error = errno;
    unlink(temporary.c_str());
    throw std::runtime_error("cannot rename " + temporary + " to " + final_path.string() + ": " +
                             std::strerror(error));
  }
  SyncFolder(final_path.parent_path());
}

std::map<int32_t, int64_t> CocoWriter::LostPerGenerator() const {
  // first seq, last seq and count per generator; the index is sorted by generator, then seq
  struct Span {
    int64_t first = 0, last = 0, count = 0;
  };
  std::map<int32_t, Span> spans;
  for (const auto& [image_id, entry] : index_) {
    Span& span = spans[entry.generator_id];
    if (span.count == 0) span.first = entry.seq;
    span.last = entry.seq;
    ++span.count;
  }
  std::map<int32_t, int64_t> lost;
  for (const auto& [generator_id, span] : spans) {
    lost[generator_id] = span.last - span.first + 1 - span.count;
  }
  return lost;
}

int64_t CocoWriter::num_lost() const {
  int64_t total = 0;
  for (const auto& [generator_id, lost] : LostPerGenerator()) total += lost;
  return total;
}

int64_t CocoWriter::StoredThrough(int32_t generator_id) const {
  const auto found = stored_through_.find(generator_id);
  return found == stored_through_.end() ? -1 : found->second;
}

bool CocoWriter::Has(int32_t generator_id, int64_t seq) const {
  if (!SceneIdsInRange(generator_id, seq)) return false;
  return index_.count(ImageId(generator_id, seq)) != 0;
}

void CocoWriter::SetRun(int32_t generator_id, const std::string& run) { runs_[generator_id] = run; }

std::map<int32_t, std::vector<int64_t>> CocoWriter::StoredSeqs() const {
  // the index is sorted by generator, then seq
  std::map<int32_t, std::vector<int64_t>> seqs;
  for (const auto& [image_id, entry] : index_) seqs[entry.generator_id].push_back(entry.seq);
  return seqs;
}

}  // namespace stackgen
