#pragma once
// Files written so that a crash never leaves one half-written: the system calls every dataset
// writer (stackgen-coco, stackgen-bop) shares, each failure thrown with the file and the
// system's reason.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace stackgen {

/// "<what> <path>: <the system's reason for error_number>".
std::runtime_error SystemError(const std::string& what, const std::string& path, int error_number);

/// The size of the file `path` in bytes, -1 if there is none. Throws if it cannot be looked at.
int64_t FileSize(const std::string& path);

/// Closes a file descriptor at scope exit.
class ScopedFd {
 public:
  explicit ScopedFd(int fd) : fd_(fd) {}
  ~ScopedFd();
  ScopedFd(const ScopedFd&) = delete;
  ScopedFd& operator=(const ScopedFd&) = delete;
  int get() const { return fd_; }
  /// Closes now; the errno of a failed close, else 0.
  int Close();

 private:
  int fd_;
};

/// Writes all `size` bytes at the file position (offset < 0) or at `offset`; the errno of the
/// first failure, else 0.
int WriteAll(int fd, const char* bytes, size_t size, int64_t offset = -1);

/// `length` bytes of `fd` (the file `path`, for the message) at `offset`; throws if it cannot.
std::string ReadAt(int fd, uint64_t offset, uint64_t length, const std::string& path);

/// The whole file `path`; throws naming it and the reason if it cannot be read.
std::string ReadWholeFile(const std::string& path);

/// Whether `name` is a temporary file of WriteFileAtomically or WriteFileWhole (it ends in ".tmp"):
/// one a crash left behind, to be removed when a writer opens its dataset again.
bool IsTemporaryFile(const std::string& name);

/// Removes the temporary files (IsTemporaryFile) in folder `path`, if it exists; throws naming
/// a file it cannot remove.
void RemoveTemporaryFiles(const std::filesystem::path& path);

/// Makes the entries of folder `path` (files created, renamed or removed in it) durable.
void SyncFolder(const std::filesystem::path& path);

/// Writes `size` bytes to `path` through `path`.tmp, renamed into place: with `sync`, the file
/// is synced before the rename and the folder after it. On failure removes what it wrote and
/// throws naming the file and the reason.
void WriteFileAtomically(const std::filesystem::path& path, const char* bytes, size_t size,
                         bool sync);

/// Creates folder `path` and its missing parents, each new one made durable in its parent;
/// returns those it created, deepest first (to remove them again, empty, on failure).
std::vector<std::filesystem::path> CreateFolders(const std::filesystem::path& path);

/// A file written through a buffer; every failure throws naming the file and the reason.
class OutputFile {
 public:
  /// Creates (or truncates) `path`.
  explicit OutputFile(std::string path);
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  void Write(std::string_view text);
  /// Writes what is buffered, syncs the file to disk and closes it.
  void Close();

 private:
  static constexpr size_t kFlushBytes = 1 << 20;
  void Flush();

  std::string path_;
  int fd_ = -1;
  std::string buffer_;
};

/// Writes a whole file through `path`.tmp: `write` fills it, then it is synced, renamed into
/// place and the folder synced, so `path` is either the old file or the whole new one. On
/// failure the temporary file is removed and the error rethrown.
template <typename WriteContents>
void WriteFileWhole(const std::filesystem::path& path, WriteContents write) {
  const std::string temporary = path.string() + ".tmp";
  try {
    OutputFile out(temporary);
    write(out);
    out.Close();
  } catch (...) {
    std::filesystem::remove(temporary);
    throw;
  }
  std::error_code error;
  std::filesystem::rename(temporary, path, error);
  if (error) {
    std::filesystem::remove(temporary);
    throw std::runtime_error("cannot rename " + temporary + " to " + path.string() + ": " +
                             error.message());
  }
  SyncFolder(path.parent_path());
}

}  // namespace stackgen
