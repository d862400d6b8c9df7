#include "consumers/dataset/files.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace stackgen {

namespace fs = std::filesystem;

std::runtime_error SystemError(const std::string& what, const std::string& path, int error_number) {
  return std::runtime_error(what + " " + path + ": " + std::strerror(error_number));
}

int64_t FileSize(const std::string& path) {
  struct stat status {};
  if (stat(path.c_str(), &status) == 0) return static_cast<int64_t>(status.st_size);
  if (errno == ENOENT) return -1;
  throw SystemError("cannot read", path, errno);
}

ScopedFd::~ScopedFd() {
  if (fd_ >= 0) close(fd_);
}

int ScopedFd::Close() {
  const int result = close(fd_);
  fd_ = -1;
  return result == 0 ? 0 : errno;
}

int WriteAll(int fd, const char* bytes, size_t size, int64_t offset) {
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

std::string ReadWholeFile(const std::string& path) {
  ScopedFd file(open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (file.get() < 0) throw SystemError("cannot read", path, errno);
  struct stat status {};
  if (fstat(file.get(), &status) != 0) throw SystemError("cannot read", path, errno);
  return ReadAt(file.get(), 0, static_cast<uint64_t>(status.st_size), path);
}

bool IsTemporaryFile(const std::string& name) {
  constexpr std::string_view kSuffix = ".tmp";
  return name.size() > kSuffix.size() &&
         name.compare(name.size() - kSuffix.size(), kSuffix.size(), kSuffix) == 0;
}

void RemoveTemporaryFiles(const fs::path& path) {
  std::error_code error;
  for (fs::directory_iterator it(path, error), end; !error && it != end; it.increment(error)) {
    if (IsTemporaryFile(it->path().filename().string()) && unlink(it->path().c_str()) != 0) {
      throw SystemError("cannot remove", it->path().string(), errno);
    }
  }
}

void SyncFolder(const fs::path& path) {
  const std::string name = path.empty() ? "." : path.string();
  ScopedFd folder(open(name.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (folder.get() < 0) throw SystemError("cannot open", name, errno);
  // a file system that cannot sync a folder says EINVAL; it has nothing more to do
  if (fsync(folder.get()) != 0 && errno != EINVAL) throw SystemError("cannot sync", name, errno);
}

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

std::vector<fs::path> CreateFolders(const fs::path& path) {
  std::vector<fs::path> created;
  std::error_code error;
  for (fs::path missing = path;
       !missing.empty() && missing != missing.parent_path() && !fs::exists(missing, error);
       missing = missing.parent_path()) {
    created.push_back(missing);
  }
  fs::create_directories(path, error);
  if (error) throw std::runtime_error("cannot create " + path.string() + ": " + error.message());
  try {
    for (const fs::path& folder : created) SyncFolder(folder.parent_path());
  } catch (...) {
    std::error_code ignored;
    for (const fs::path& folder : created) fs::remove(folder, ignored);  // only if empty
    throw;
  }
  return created;
}

OutputFile::OutputFile(std::string path) : path_(std::move(path)) {
  fd_ = open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) throw SystemError("cannot create", path_, errno);
}

OutputFile::~OutputFile() {
  if (fd_ >= 0) close(fd_);
}

void OutputFile::Write(std::string_view text) {
  buffer_.append(text);
  if (buffer_.size() >= kFlushBytes) Flush();
}

void OutputFile::Close() {
  Flush();
  if (fsync(fd_) != 0) throw SystemError("cannot write", path_, errno);
  const int result = close(fd_);
  fd_ = -1;
  if (result != 0) throw SystemError("cannot write", path_, errno);
}

void OutputFile::Flush() {
  const int error = WriteAll(fd_, buffer_.data(), buffer_.size());
  if (error != 0) throw SystemError("cannot write", path_, error);
  buffer_.clear();
}

}  // namespace stackgen
