#include "consumers/dataset/dataset_sink.h"

#include <map>
#include <optional>
#include <string>

#include <gtest/gtest.h>

namespace stackgen {
namespace {

scene Scene(int32_t generator_id, int64_t seq, int64_t seed) {
  scene message{};
  message.header.generator_id = generator_id;
  message.header.seq = seq;
  message.header.seed = seed;
  return message;
}

// the checks both writers make first: ids inside the layout; a repeat is the same scene only
// with the same seed, another seed is another run with the same --generator-id
TEST(DatasetSinkTest, IdsAndRepeats) {
  EXPECT_NO_THROW(CheckSceneIds(Scene(3, 7, 1)));
  try {
    CheckSceneIds(Scene(3, -1, 1));
    FAIL() << "a negative seq passed";
  } catch (const InvalidSceneError& error) {
    EXPECT_EQ(std::string(error.what()).rfind("scene 3/-1: generator_id or seq outside", 0), 0u)
        << error.what();
  }
  EXPECT_THROW(CheckSceneIds(Scene(70000, 0, 1)), InvalidSceneError);
  EXPECT_FALSE(IsRepeat(Scene(3, 7, 11), std::nullopt));
  EXPECT_TRUE(IsRepeat(Scene(3, 7, 11), 11));
  try {
    IsRepeat(Scene(3, 7, 12), 11);
    FAIL() << "another seed passed as a repeat";
  } catch (const InvalidSceneError& error) {
    EXPECT_EQ(std::string(error.what()),
              "scene 3/7: header.seed 12 differs from the stored scene's 11: another run with the "
              "same --generator-id (give each run its own id, or write it to another --out)");
  }
}

// the seed a scene was stored with comes first, then the one it was staged with
TEST(DatasetSinkTest, SeenSeedLooksInStoredThenStaged) {
  struct Entry {
    int64_t seed;
  };
  const std::map<int64_t, Entry> stored = {{1, {5}}, {2, {6}}};
  const std::map<int64_t, int64_t> staged = {{2, 8}, {3, 7}};
  EXPECT_EQ(SeenSeed(stored, staged, int64_t{1}), std::optional<int64_t>(5));
  EXPECT_EQ(SeenSeed(stored, staged, int64_t{2}), std::optional<int64_t>(6));
  EXPECT_EQ(SeenSeed(stored, staged, int64_t{3}), std::optional<int64_t>(7));
  EXPECT_EQ(SeenSeed(stored, staged, int64_t{4}), std::nullopt);
}

TEST(DatasetSinkTest, LostBetweenCountsTheGaps) {
  const std::map<int32_t, int64_t> lost = LostBetween({{0, {0, 1, 4}}, {2, {}}, {5, {7, 8}}});
  EXPECT_EQ(lost, (std::map<int32_t, int64_t>{{0, 2}, {5, 0}}));
}

}  // namespace
}  // namespace stackgen
