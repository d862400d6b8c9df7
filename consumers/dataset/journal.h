#pragma once
// The durable record of a dataset writer: a file of lines, one per scene stored, each complete
// once its '\n' is written and synced. A crash can leave a torn last line only; Load cuts it off.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace stackgen {

/// The error for a dataset folder whose journal (`journal_path`) already holds scenes, when a new
/// dataset was asked for: it names the file and says to use --resume or another folder.
std::runtime_error DatasetStartedError(const std::string& journal_path);

/// An append-only journal of lines, locked against a second writer. Not thread-safe.
class Journal {
 public:
  /// Opens `path`, creating it empty if missing, and locks it. Throws std::runtime_error naming
  /// the file if it cannot be opened or another writer holds it ("is in use by another writer").
  explicit Journal(std::string path);
  ~Journal();
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;

  /// Calls `on_line(line, offset, line_number)` for every complete line in order (without its
  /// '\n'; offset: of its first byte; numbers from 1), then cuts a torn last line off, durably.
  /// Returns the bytes cut off. What `on_line` throws goes through (nothing is cut then).
  int64_t Load(const std::function<void(const std::string& line, uint64_t offset,
                                        int64_t line_number)>& on_line);

  /// Appends `lines` (whole lines, each ending in '\n') in one write and syncs them. On failure
  /// cuts the journal back to where it was and throws naming the file and the reason; if even
  /// that fails, every later Append throws until the journal is loaded again by a new writer.
  void Append(const std::string& lines);

  /// `length` bytes at `offset`; throws naming the file if it cannot read them.
  std::string Read(uint64_t offset, uint64_t length) const;

  /// Whether a failed Append could not be cut back: the journal may end with lines that
  /// were not committed (keep what they record; a resume sorts it out).
  bool broken() const { return broken_; }
  /// Bytes in the journal (its complete lines, after Load).
  uint64_t size() const { return size_; }
  const std::string& path() const { return path_; }
  /// The open file, e.g. for syncfs of the file system it is on.
  int fd() const { return fd_; }

 private:
  std::string path_;
  int fd_ = -1;
  uint64_t size_ = 0;
  bool broken_ = false;  // a failed append could not be cut back
};

/// Makes a group of staged scenes durable, the same way for every dataset writer: first the
/// files they wrote (with `sync_files`: one syncfs of the file system the journal is on; the
/// error names `files_name`), then their journal `lines` in one write and one sync. On failure
/// removes `files` (unless the journal may record them: Journal::broken) and rethrows; the caller
/// drops what it staged. Returns the offset in the journal of the group's first line.
uint64_t CommitGroup(Journal* journal, const std::vector<std::string>& lines,
                     const std::vector<std::string>& files, bool sync_files,
                     const std::string& files_name);

/// Opening a dataset again: clears what an interrupted run left in `folder` (nothing if the
/// folder is missing): temporary files (IsTemporaryFile), and with `remove_unrecorded` the files
/// `is_ours` accepts that `recorded` (paths relative to `root`, as the journal names them) does
/// not name: an Add that never completed wrote them. Returns how many files of `recorded` it
/// found in `folder`. Throws naming a file it cannot remove, or the folder if it cannot read it.
size_t CleanUnrecorded(const std::filesystem::path& root, const std::filesystem::path& folder,
                       const std::set<std::string>& recorded, bool remove_unrecorded,
                       const std::function<bool(const std::string& name)>& is_ours);

/// Throws unless every file `recorded` names (relative to `root`) is there ("... is missing,
/// though JOURNAL records it (the dataset is damaged)"); `present`: how many CleanUnrecorded
/// found, so that nothing is looked up when all were.
void CheckRecordedFiles(const std::filesystem::path& root, const std::set<std::string>& recorded,
                        size_t present, const std::string& journal_path);

}  // namespace stackgen
