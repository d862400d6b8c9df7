#include "consumers/dataset/shards.h"

#include <fcntl.h>
#include <unistd.h>

#include <archive.h>
#include <archive_entry.h>

#include <cerrno>
#include <cstdio>
#include <stdexcept>

#include "consumers/dataset/files.h"

namespace stackgen {

int64_t ShardOf(int64_t chunk, int64_t image, int shard_images) {
  const int64_t per_chunk = (kImagesPerChunk + shard_images - 1) / shard_images;
  return chunk * per_chunk + image / shard_images;
}

std::string ShardFileName(int64_t shard) {
  char name[64];
  std::snprintf(name, sizeof(name), "shard-%06lld.tar", static_cast<long long>(shard));
  return name;
}

void WriteTar(const std::filesystem::path& path,
              const std::vector<std::pair<std::string, std::string>>& members) {
  const std::string temporary = path.string() + ".tmp";
  struct archive* tar = archive_write_new();
  const auto fail = [&](const std::string& what) {
    const char* reason = archive_error_string(tar);
    const std::string text = "cannot write " + temporary + ": " + what +
                             (reason != nullptr ? " (" + std::string(reason) + ")" : "");
    archive_write_free(tar);
    unlink(temporary.c_str());
    throw std::runtime_error(text);
  };
  if (archive_write_set_format_ustar(tar) != ARCHIVE_OK ||
      archive_write_open_filename(tar, temporary.c_str()) != ARCHIVE_OK) {
    fail("cannot open it");
  }
  for (const auto& [name, bytes] : members) {
    struct archive_entry* entry = archive_entry_new();
    archive_entry_set_pathname(entry, name.c_str());
    archive_entry_set_size(entry, static_cast<la_int64_t>(bytes.size()));
    archive_entry_set_filetype(entry, AE_IFREG);
    archive_entry_set_perm(entry, 0644);
    archive_entry_set_mtime(entry, 0, 0);
    const bool written = archive_write_header(tar, entry) == ARCHIVE_OK &&
                         archive_write_data(tar, bytes.data(), bytes.size()) ==
                             static_cast<la_ssize_t>(bytes.size());
    archive_entry_free(entry);
    if (!written) fail(name);
  }
  if (archive_write_close(tar) != ARCHIVE_OK) fail("cannot close it");
  archive_write_free(tar);
  // durable before it takes the old shard's place
  {
    ScopedFd file(open(temporary.c_str(), O_RDONLY | O_CLOEXEC));
    if (file.get() < 0 || fsync(file.get()) != 0) {
      const int error = errno;
      unlink(temporary.c_str());
      throw SystemError("cannot sync", temporary, error);
    }
  }
  if (rename(temporary.c_str(), path.c_str()) != 0) {
    const int error = errno;
    unlink(temporary.c_str());
    throw SystemError("cannot rename " + temporary + " to", path.string(), error);
  }
  SyncFolder(path.parent_path());
}

void WriteKeyToShard(const std::filesystem::path& path,
                     const std::map<std::string, int64_t>& keys) {
  // keys are file name stems (digits and '_'): nothing in them needs escaping
  WriteFileWhole(path, [&](OutputFile& out) {
    out.Write("{\n");
    size_t written = 0;
    for (const auto& [key, shard] : keys) {
      out.Write("  \"" + key + "\": " + std::to_string(shard) +
                (++written < keys.size() ? ",\n" : "\n"));
    }
    out.Write("}");
  });
}

}  // namespace stackgen
