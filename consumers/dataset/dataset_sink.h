#pragma once
// What a dataset writer program (consumers/dataset/writer_main.h) needs of the dataset it fills.

#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <stackgen/scene.hpp>

namespace stackgen {

/// Thrown by DatasetSink::Add for a scene whose contents disagree with each other; the text
/// names the scene (generator_id/seq) and the field at fault. Nothing of such a scene is written.
class InvalidSceneError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A dataset on disk that stores scenes once each, durably, from a journal it can be resumed
/// from (CocoWriter, BopWriter document the details).
class DatasetSink {
 public:
  virtual ~DatasetSink() = default;
  /// Validates and stores `scene`, durably when it returns; a sink opened with group commits
  /// only stages it (Commit makes it durable). False, writing nothing, for a scene stored or
  /// staged already. Throws InvalidSceneError for a bad scene and
  /// std::runtime_error for a write error; either way nothing of the scene is kept.
  virtual bool Add(const scene& scene) = 0;
  /// Makes the staged scenes durable; returns their (generator_id, seq) in the order added.
  virtual std::vector<std::pair<int32_t, int64_t>> Commit() = 0;
  /// Scenes added but not yet committed.
  virtual int64_t num_staged() const = 0;
  /// Scenes stored (those resumed included).
  virtual int64_t num_images() const = 0;
  /// Commits, then writes the files derived from the journal.
  virtual void Finish() = 0;
  /// What Finish writes, for messages: "annotations.json".
  virtual std::string finished_files() const = 0;
  /// The run (session/delivery.h RunName) each generator's scenes come from.
  virtual const std::map<int32_t, std::string>& Runs() const = 0;
  /// Scenes of `generator_id` added from now on are journalled as coming from `run`.
  virtual void SetRun(int32_t generator_id, const std::string& run) = 0;
  /// Every stored seq, ascending, per generator_id.
  virtual std::map<int32_t, std::vector<int64_t>> StoredSeqs() const = 0;
  /// Per generator_id, the seqs missing between the first and the last seq stored.
  virtual std::map<int32_t, int64_t> LostPerGenerator() const = 0;
  /// The sum of LostPerGenerator.
  int64_t num_lost() const {
    int64_t total = 0;
    for (const auto& [generator_id, lost] : LostPerGenerator()) total += lost;
    return total;
  }
  /// Bytes of a torn last journal line cut off on resume.
  virtual int64_t truncated_journal_bytes() const = 0;
};

/// The checks every DatasetSink::Add makes first, in one place.
///
/// The scene's name in errors: "scene <generator_id>/<seq>".
std::string SceneName(const scene& scene);
/// Throws InvalidSceneError("scene G/S: `text`").
[[noreturn]] void FailScene(const scene& scene, const std::string& text);
/// Throws InvalidSceneError when the scene's generator_id or seq is outside the id layout
/// (contract/scene_contract.h).
void CheckSceneIds(const scene& scene);
/// Whether `scene` repeats the scene stored or staged with its ids, whose seed was `seen_seed`
/// (none stored or staged: std::nullopt): true means store nothing. Throws InvalidSceneError when
/// the seeds differ: another run with the same --generator-id.
bool IsRepeat(const scene& scene, std::optional<int64_t> seen_seed);
/// The seed the scene with `key` was stored with (`stored`: key -> an entry with a `seed`) or
/// staged with (`staged`: key -> seed), for IsRepeat; std::nullopt when it is neither.
template <typename Stored, typename Staged, typename Key>
std::optional<int64_t> SeenSeed(const Stored& stored, const Staged& staged, const Key& key) {
  if (const auto found = stored.find(key); found != stored.end()) return found->second.seed;
  if (const auto found = staged.find(key); found != staged.end()) return found->second;
  return std::nullopt;
}

/// Whether `text` is valid UTF-8, as the JSON files of a dataset must be (class names come from
/// the bus).
bool IsUtf8(const std::string& text);

/// Per generator, the seqs missing between the first and the last of `seqs` (ascending).
std::map<int32_t, int64_t> LostBetween(const std::map<int32_t, std::vector<int64_t>>& seqs);

}  // namespace stackgen
