#include "consumers/dataset/dataset_sink.h"

#include <nlohmann/json.hpp>

#include "contract/scene_contract.h"

namespace stackgen {

std::string SceneName(const scene& scene) {
  return "scene " + std::to_string(scene.header.generator_id) + "/" +
         std::to_string(scene.header.seq);
}

void FailScene(const scene& scene, const std::string& text) {
  throw InvalidSceneError(SceneName(scene) + ": " + text);
}

void CheckSceneIds(const scene& scene) {
  if (!SceneIdsInRange(scene.header.generator_id, scene.header.seq)) {
    FailScene(scene, "generator_id or seq outside the id layout (generator_id 0.." +
                         std::to_string(kMaxGeneratorId) + ", seq 0.." + std::to_string(kMaxSeq) +
                         ")");
  }
}

bool IsRepeat(const scene& scene, std::optional<int64_t> seen_seed) {
  if (!seen_seed) return false;
  if (*seen_seed != scene.header.seed) {
    FailScene(scene, "header.seed " + std::to_string(scene.header.seed) +
                         " differs from the stored scene's " + std::to_string(*seen_seed) +
                         ": another run with the same --generator-id (give each run its own "
                         "id, or write it to another --out)");
  }
  return true;
}

bool IsUtf8(const std::string& text) {
  try {
    nlohmann::json(text).dump();
    return true;
  } catch (const nlohmann::json::type_error&) {
    return false;
  }
}

std::map<int32_t, int64_t> LostBetween(const std::map<int32_t, std::vector<int64_t>>& seqs) {
  std::map<int32_t, int64_t> lost;
  for (const auto& [generator_id, stored] : seqs) {
    if (stored.empty()) continue;
    lost[generator_id] = stored.back() - stored.front() + 1 - static_cast<int64_t>(stored.size());
  }
  return lost;
}

}  // namespace stackgen
