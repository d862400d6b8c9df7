#pragma once
// Webdataset tar shards of a dataset (as BOP-webdataset has them: bop_toolkit
// bop_toolkit_lib/dataset/bop_webdataset.py), shared by stackgen-bop and stackgen-coco: which
// shard an image goes to, the tar files, and key_to_shard.json.

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace stackgen {

/// Images of one chunk: 1000 consecutive seqs of one generator (BOP's scene folder).
inline constexpr int64_t kImagesPerChunk = 1000;

/// The shard of image `image` (0..999) of chunk `chunk` with at most `shard_images` (1..1000)
/// images per shard: chunk * ceil(1000 / shard_images) + image / shard_images. A shard holds
/// consecutive images of one chunk, whatever order they arrive in.
int64_t ShardOf(int64_t chunk, int64_t image, int shard_images);

/// "shard-000012.tar" (six digits at least, as the toolkit names them).
std::string ShardFileName(int64_t shard);

/// Writes the tar file `path` of `members` (name, bytes) in that order: ustar, every member
/// 0644, owned by 0:0 and dated 0, so the same members give the same bytes. Through a temporary
/// file, synced, renamed into place, the folder synced; libarchive writes the format. Throws
/// std::runtime_error naming the file and the reason.
void WriteTar(const std::filesystem::path& path,
              const std::vector<std::pair<std::string, std::string>>& members);

/// Writes key_to_shard.json at `path` as the toolkit's inout.save_json writes a dict: every key
/// (in key order) -> its shard, one per line. Whole, through a temporary file.
void WriteKeyToShard(const std::filesystem::path& path, const std::map<std::string, int64_t>& keys);

}  // namespace stackgen
