// The storage both dataset writers build on, tested on its own: the journal (records, a torn
// last line, the lock, a failed append cut back), crash-safe files (written whole or not at all,
// leftovers removed, folders created) and webdataset shards (which shard, the tar bytes,
// key_to_shard.json).

#include <signal.h>
#include <sys/resource.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "consumers/dataset/files.h"
#include "consumers/dataset/journal.h"
#include "consumers/dataset/shards.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;

std::string Contents(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

struct Line {
  std::string text;
  uint64_t offset;
  int64_t number;
  bool operator==(const Line& other) const {
    return text == other.text && offset == other.offset && number == other.number;
  }
};

// runs `body` with files of this process limited to `bytes` (RLIMIT_FSIZE, as a full disk
// would stop a write half-way: the write fails with EFBIG, SIGXFSZ ignored), then lifts it
void WithFileSizeLimit(rlim_t bytes, const std::function<void()>& body) {
  struct sigaction ignore = {}, old_action = {};
  ignore.sa_handler = SIG_IGN;
  sigaction(SIGXFSZ, &ignore, &old_action);
  rlimit old_limit{};
  getrlimit(RLIMIT_FSIZE, &old_limit);
  rlimit small = old_limit;
  small.rlim_cur = bytes;
  const bool limited = setrlimit(RLIMIT_FSIZE, &small) == 0;
  EXPECT_TRUE(limited);
  if (limited) body();
  setrlimit(RLIMIT_FSIZE, &old_limit);
  sigaction(SIGXFSZ, &old_action, nullptr);
}

std::vector<Line> LoadAll(Journal* journal, int64_t* cut = nullptr) {
  std::vector<Line> lines;
  const int64_t bytes =
      journal->Load([&](const std::string& text, uint64_t offset, int64_t number) {
        lines.push_back({text, offset, number});
      });
  if (cut != nullptr) *cut = bytes;
  return lines;
}

// records appended are there, in order, with their offsets, after the journal is opened again
TEST(JournalTest, RecordsComeBackInOrder) {
  testing::ScratchDir scratch("journal");
  const std::string path = scratch.path() + "/a.journal";
  {
    Journal journal(path);
    EXPECT_TRUE(LoadAll(&journal).empty());
    journal.Append("first\n");
    journal.Append("second\nthird\n");
    EXPECT_EQ(journal.size(), 19u);
  }
  Journal journal(path);
  int64_t cut = -1;
  EXPECT_EQ(LoadAll(&journal, &cut),
            (std::vector<Line>{{"first", 0, 1}, {"second", 6, 2}, {"third", 13, 3}}));
  EXPECT_EQ(cut, 0);
  EXPECT_EQ(journal.Read(6, 6), "second");
}

// a crash in the middle of a write leaves a last line without its '\n': Load hands out the
// complete lines only, cuts the torn one off the file, and the next record starts clean
TEST(JournalTest, TornLastLineIsCutOff) {
  testing::ScratchDir scratch("journal");
  const std::string path = scratch.path() + "/a.journal";
  std::ofstream(path, std::ios::binary) << "whole\nto";
  Journal journal(path);
  int64_t cut = -1;
  EXPECT_EQ(LoadAll(&journal, &cut), (std::vector<Line>{{"whole", 0, 1}}));
  EXPECT_EQ(cut, 2);
  EXPECT_EQ(FileSize(path), 6);
  journal.Append("next\n");
  EXPECT_EQ(Contents(path), "whole\nnext\n");
}

// one writer per dataset: a second journal on the same file is refused while the first is open
TEST(JournalTest, SecondWriterIsRefused) {
  testing::ScratchDir scratch("journal");
  const std::string path = scratch.path() + "/a.journal";
  auto first = std::make_unique<Journal>(path);
  try {
    Journal second(path);
    FAIL() << "a second writer opened " << path;
  } catch (const std::runtime_error& error) {
    EXPECT_EQ(std::string(error.what()),
              path + " is in use by another writer (one writer per dataset folder)");
  }
  first.reset();
  EXPECT_NO_THROW(Journal again(path));
}

// a write that fails half-way (here: the file size limit, as a full disk would) throws naming
// the file, and the journal is cut back to its last complete record; the next append works
TEST(JournalTest, FailedAppendIsCutBack) {
  testing::ScratchDir scratch("journal");
  const std::string path = scratch.path() + "/a.journal";
  Journal journal(path);
  LoadAll(&journal);
  journal.Append("kept\n");
  std::string what;
  WithFileSizeLimit(16, [&] {
    try {
      journal.Append(std::string(40, 'x') + "\n");
    } catch (const std::runtime_error& error) {
      what = error.what();
    }
  });
  EXPECT_EQ(what.rfind("cannot write " + path + ": ", 0), 0u) << what;
  EXPECT_FALSE(journal.broken());
  EXPECT_EQ(Contents(path), "kept\n");
  journal.Append("after\n");
  EXPECT_EQ(Contents(path), "kept\nafter\n");
}

// a group commit: the files first, then the lines in one write; the first line's offset comes
// back; a group that cannot be recorded takes its files with it
TEST(JournalTest, GroupCommitRecordsOrRemovesItsFiles) {
  testing::ScratchDir scratch("journal");
  const std::string path = scratch.path() + "/a.journal";
  Journal journal(path);
  LoadAll(&journal);
  journal.Append("before\n");
  const std::string image = scratch.path() + "/a.png";
  std::ofstream(image) << "png";
  EXPECT_EQ(CommitGroup(&journal, {"one\n", "two\n"}, {image}, true, scratch.path()), 7u);
  EXPECT_EQ(Contents(path), "before\none\ntwo\n");
  EXPECT_TRUE(fs::exists(image));

  const std::string lost = scratch.path() + "/b.png";
  std::ofstream(lost) << "png";
  WithFileSizeLimit(20, [&] {
    EXPECT_THROW(CommitGroup(&journal, {std::string(30, 'x') + "\n"}, {lost}, false, ""),
                 std::runtime_error);
  });
  EXPECT_FALSE(fs::exists(lost));
  EXPECT_EQ(Contents(path), "before\none\ntwo\n");
}

TEST(JournalTest, StartedDatasetErrorSaysWhatToDo) {
  EXPECT_EQ(std::string(DatasetStartedError("/d/annotations.journal").what()),
            "/d/annotations.journal already exists (a dataset was started here); will not "
            "overwrite it (use --resume to continue it, or choose another output folder)");
}

// opening a dataset again: temporary files go; with remove_unrecorded, the writer's own files
// that no journal line names go too (other files stay); recorded files are counted, and one
// missing is named with the journal
TEST(JournalTest, ReopeningCleansWhatNoLineRecords) {
  testing::ScratchDir scratch("reopen");
  const fs::path root = scratch.path();
  const fs::path images = root / "chunk" / "rgb";
  fs::create_directories(images);
  for (const char* name : {"000000.png", "000001.png", "000002.png.tmp", "notes.txt"}) {
    std::ofstream(images / name) << "x";
  }
  const std::set<std::string> recorded = {"chunk/rgb/000000.png"};
  const auto png = [](const std::string& name) { return fs::path(name).extension() == ".png"; };
  const auto names = [&] {
    std::set<std::string> found;
    for (const auto& entry : fs::directory_iterator(images)) {
      found.insert(entry.path().filename().string());
    }
    return found;
  };
  EXPECT_EQ(CleanUnrecorded(root, images, recorded, false, png), 1u);
  EXPECT_EQ(names(), (std::set<std::string>{"000000.png", "000001.png", "notes.txt"}));
  EXPECT_EQ(CleanUnrecorded(root, images, recorded, true, png), 1u);
  EXPECT_EQ(names(), (std::set<std::string>{"000000.png", "notes.txt"}));
  EXPECT_EQ(CleanUnrecorded(root, root / "missing", recorded, true, png), 0u);
  EXPECT_NO_THROW(CheckRecordedFiles(root, recorded, 1, "j"));
  const std::set<std::string> more = {"chunk/rgb/000000.png", "chunk/rgb/000009.png"};
  try {
    CheckRecordedFiles(root, more, 1, "/d/bop.journal");
    ADD_FAILURE() << "a missing recorded file was not found out";
  } catch (const std::runtime_error& error) {
    EXPECT_EQ(std::string(error.what()),
              (root / "chunk/rgb/000009.png").string() +
                  " is missing, though /d/bop.journal records it (the dataset is damaged)");
  }
}

// a file is the old one or the whole new one, never a part; what fails leaves no .tmp behind
TEST(FilesTest, WrittenWholeOrNotAtAll) {
  testing::ScratchDir scratch("files");
  const fs::path path = fs::path(scratch.path()) / "a.json";
  WriteFileAtomically(path, "old", 3, true);
  WriteFileAtomically(path, "new contents", 12, true);
  EXPECT_EQ(Contents(path), "new contents");
  EXPECT_FALSE(fs::exists(path.string() + ".tmp"));
  // a writer that fails half-way: the old file stays, no temporary file
  EXPECT_THROW(WriteFileWhole(path,
                              [](OutputFile& out) {
                                out.Write("half");
                                throw std::runtime_error("stopped");
                              }),
               std::runtime_error);
  EXPECT_EQ(Contents(path), "new contents");
  EXPECT_FALSE(fs::exists(path.string() + ".tmp"));
  // a rename that cannot happen (a folder is in the way): an error naming both, nothing left
  const fs::path folder = fs::path(scratch.path()) / "taken";
  fs::create_directories(folder / "inside");
  try {
    WriteFileAtomically(folder, "x", 1, false);
    FAIL() << "wrote over a folder";
  } catch (const std::runtime_error& error) {
    EXPECT_EQ(
        std::string(error.what())
            .rfind("cannot rename " + folder.string() + ".tmp to " + folder.string() + ": ", 0),
        0u)
        << error.what();
  }
  EXPECT_FALSE(fs::exists(folder.string() + ".tmp"));
  EXPECT_EQ(FileSize((fs::path(scratch.path()) / "missing").string()), -1);
}

// what a crash left behind (name.tmp) is removed when a writer opens its dataset again, and
// nothing else; folders are created with their parents, deepest first in the list
TEST(FilesTest, LeftoversAndFolders) {
  testing::ScratchDir scratch("files");
  const fs::path root(scratch.path());
  for (const char* name : {"a.json.tmp", "b.json", ".tmp", "c.tmpx"}) {
    std::ofstream(root / name) << "x";
  }
  EXPECT_TRUE(IsTemporaryFile("a.json.tmp"));
  EXPECT_FALSE(IsTemporaryFile(".tmp"));
  RemoveTemporaryFiles(root);
  EXPECT_FALSE(fs::exists(root / "a.json.tmp"));
  for (const char* name : {"b.json", ".tmp", "c.tmpx"}) EXPECT_TRUE(fs::exists(root / name));
  RemoveTemporaryFiles(root / "absent");  // no folder: nothing to do

  const std::vector<fs::path> created = CreateFolders(root / "x" / "y" / "z");
  EXPECT_EQ(created, (std::vector<fs::path>{root / "x" / "y" / "z", root / "x" / "y", root / "x"}));
  EXPECT_TRUE(fs::is_directory(root / "x" / "y" / "z"));
  EXPECT_TRUE(CreateFolders(root / "x").empty());
}

// which shard an image goes to: consecutive images of one chunk, ceil(1000 / n) shards a chunk
TEST(ShardsTest, ShardOfAndNames) {
  EXPECT_EQ(ShardOf(0, 0, 100), 0);
  EXPECT_EQ(ShardOf(0, 999, 100), 9);
  EXPECT_EQ(ShardOf(2, 999, 100), 29);
  EXPECT_EQ(ShardOf(1, 0, 300), 4);  // 4 shards a chunk: 0-299, 300-599, 600-899, 900-999
  EXPECT_EQ(ShardOf(1, 950, 300), 7);
  EXPECT_EQ(ShardOf(3, 5, 1000), 3);
  EXPECT_EQ(ShardFileName(12), "shard-000012.tar");
  EXPECT_EQ(ShardFileName(1234567), "shard-1234567.tar");
}

// a tar of the same members has the same bytes, whatever the time or the user: ustar headers
// with the names and sizes, mode 0644, owner 0:0, date 0, and the contents in 512-byte blocks
TEST(ShardsTest, TarIsReproducible) {
  testing::ScratchDir scratch("shards");
  const fs::path a = fs::path(scratch.path()) / "a.tar";
  const fs::path b = fs::path(scratch.path()) / "b.tar";
  const std::vector<std::pair<std::string, std::string>> members = {
      {"000001_000002.rgb.png", std::string(700, 'p')}, {"000001_000002.gt.json", "{}"}};
  WriteTar(a, members);
  WriteTar(b, members);
  const std::string bytes = Contents(a);
  EXPECT_EQ(bytes, Contents(b));
  ASSERT_GE(bytes.size(), 512u * 5);
  // a header field: NUL-terminated within its length
  const auto field = [&](size_t header, size_t offset, size_t length) {
    const std::string raw = bytes.substr(header + offset, length);
    return raw.substr(0, raw.find('\0'));
  };
  EXPECT_EQ(field(0, 0, 100), "000001_000002.rgb.png");
  EXPECT_EQ(std::stoll(field(0, 124, 12), nullptr, 8), 700);
  EXPECT_EQ(std::stoll(field(0, 100, 8), nullptr, 8), 0644);
  EXPECT_EQ(std::stoll(field(0, 108, 8), nullptr, 8), 0);
  EXPECT_EQ(std::stoll(field(0, 136, 12), nullptr, 8), 0);
  EXPECT_EQ(bytes.compare(257, 5, "ustar"), 0);
  EXPECT_EQ(bytes.substr(512, 700), std::string(700, 'p'));
  const size_t second = 512 + 1024;  // 700 bytes take two blocks
  EXPECT_EQ(field(second, 0, 100), "000001_000002.gt.json");
  EXPECT_EQ(bytes.substr(second + 512, 2), "{}");
  EXPECT_FALSE(fs::exists(a.string() + ".tmp"));
}

TEST(ShardsTest, KeyToShardAsTheToolkitWritesIt) {
  testing::ScratchDir scratch("shards");
  const fs::path path = fs::path(scratch.path()) / "key_to_shard.json";
  WriteKeyToShard(path, {{"000001_000002", 3}, {"000000_000007", 0}});
  EXPECT_EQ(Contents(path), "{\n  \"000000_000007\": 0,\n  \"000001_000002\": 3\n}");
}

}  // namespace
}  // namespace stackgen
