#include "consumers/dataset/journal.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <vector>

#include "consumers/dataset/files.h"

namespace stackgen {

std::runtime_error DatasetStartedError(const std::string& journal_path) {
  return std::runtime_error(journal_path +
                            " already exists (a dataset was started here); will not overwrite it "
                            "(use --resume to continue it, or choose another output folder)");
}

Journal::Journal(std::string path) : path_(std::move(path)) {
  fd_ = open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) throw SystemError("cannot open", path_, errno);
  if (flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    close(fd_);
    fd_ = -1;
    if (error == EWOULDBLOCK) {
      throw std::runtime_error(path_ +
                               " is in use by another writer (one writer per dataset folder)");
    }
    throw SystemError("cannot lock", path_, error);
  }
  const int64_t size = FileSize(path_);
  size_ = size > 0 ? static_cast<uint64_t>(size) : 0;
}

Journal::~Journal() {
  if (fd_ >= 0) close(fd_);
}

int64_t Journal::Load(const std::function<void(const std::string&, uint64_t, int64_t)>& on_line) {
  // line by line; a last line without its '\n' is a torn write
  std::vector<char> buffer(1 << 20);
  std::string line;
  uint64_t read_offset = 0, line_offset = 0;
  int64_t line_number = 0;
  while (true) {
    const ssize_t got = pread(fd_, buffer.data(), buffer.size(), static_cast<off_t>(read_offset));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) throw SystemError("cannot read", path_, errno);
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
      on_line(line, line_offset, ++line_number);
      line_offset += line.size() + 1;
      line.clear();
      begin = newline + 1;
    }
  }

  // cut the torn line off, durably, so the next line starts clean
  if (!line.empty()) {
    if (ftruncate(fd_, static_cast<off_t>(line_offset)) != 0 || fsync(fd_) != 0) {
      throw SystemError("cannot cut the torn last line off", path_, errno);
    }
  }
  size_ = line_offset;
  broken_ = false;
  return static_cast<int64_t>(line.size());
}

void Journal::Append(const std::string& lines) {
  if (broken_) {
    throw std::runtime_error("cannot write " + path_ +
                             ": an earlier failed write could not be cut back (resume the "
                             "dataset to repair it)");
  }
  // write and sync the lines, or cut the journal back to its last complete line
  int error = WriteAll(fd_, lines.data(), lines.size(), static_cast<int64_t>(size_));
  if (error == 0 && fsync(fd_) != 0) error = errno;
  if (error != 0) {
    if (ftruncate(fd_, static_cast<off_t>(size_)) != 0 || fsync(fd_) != 0) broken_ = true;
    throw SystemError("cannot write", path_, error);
  }
  size_ += lines.size();
}

std::string Journal::Read(uint64_t offset, uint64_t length) const {
  return ReadAt(fd_, offset, length, path_);
}

uint64_t CommitGroup(Journal* journal, const std::vector<std::string>& lines,
                     const std::vector<std::string>& files, bool sync_files,
                     const std::string& files_name) {
  try {
    if (sync_files && syncfs(journal->fd()) != 0) {
      throw SystemError("cannot sync", files_name, errno);
    }
    std::string text;
    for (const std::string& line : lines) text += line;
    journal->Append(text);
    return journal->size() - text.size();
  } catch (...) {
    if (!journal->broken()) {
      for (const std::string& path : files) unlink(path.c_str());
    }
    throw;
  }
}

size_t CleanUnrecorded(const std::filesystem::path& root, const std::filesystem::path& folder,
                       const std::set<std::string>& recorded, bool remove_unrecorded,
                       const std::function<bool(const std::string& name)>& is_ours) {
  namespace fs = std::filesystem;
  std::error_code error;
  if (!fs::is_directory(folder, error)) return 0;
  size_t present = 0;
  for (fs::directory_iterator it(folder, error), end; !error && it != end; it.increment(error)) {
    std::error_code type_error;
    if (!it->is_regular_file(type_error)) continue;
    const std::string name = it->path().filename().string();
    if (recorded.count(it->path().lexically_relative(root).string()) != 0) {
      ++present;
      continue;
    }
    if ((IsTemporaryFile(name) || (remove_unrecorded && is_ours(name))) &&
        unlink(it->path().c_str()) != 0) {
      throw SystemError("cannot remove", it->path().string(), errno);
    }
  }
  if (error) throw std::runtime_error("cannot read " + folder.string() + ": " + error.message());
  return present;
}

void CheckRecordedFiles(const std::filesystem::path& root, const std::set<std::string>& recorded,
                        size_t present, const std::string& journal_path) {
  if (present >= recorded.size()) return;
  std::error_code error;
  for (const std::string& name : recorded) {
    if (!std::filesystem::exists(root / name, error)) {
      throw std::runtime_error((root / name).string() + " is missing, though " + journal_path +
                               " records it (the dataset is damaged)");
    }
  }
}

}  // namespace stackgen
