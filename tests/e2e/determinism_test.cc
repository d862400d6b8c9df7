// Runs the stackgen program as separate processes on a free multicast port and compares the
// poses they publish on STACKGEN_LABELS and the whole scenes on STACKGEN_SCENE: a scene is a pure
// function of (config, seed, generator, scene number), bit for bit, across processes and for
// any number of physics threads.

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <stackgen/labels.hpp>
#include <stackgen/scene.hpp>
#include <string>
#include <vector>

#include "bus/bus.h"
#include "bus/channels.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::Process;

constexpr int kScenes = 4;

// One run of the generator: its labels and its scenes (encoded, publish time zeroed) by scene
// number, the scene numbers in the order the scenes arrived, its exit code and its output.
struct GeneratorRun {
  std::map<int64_t, labels> scenes;
  std::map<int64_t, std::vector<unsigned char>> whole;
  std::vector<int64_t> arrived;
  int exit_code = -1;
  std::string output;
};

// Starts `stackgen --count count --seed seed --config config` as a process, with this test
// listening on STACKGEN_LABELS of a fresh multicast port before it starts, and collects every
// scene. The process's output and cache go to the new folder `dir`.
GeneratorRun Generate(const std::string& dir, uint64_t seed,
                      const std::string& config = std::string(STACKGEN_SOURCE_DIR) +
                                                  "/config/default.pbtxt",
                      int count = kScenes, const std::vector<std::string>& flags = {}) {
  const std::string url = testing::FreeMulticastUrl();
  mkdir(dir.c_str(), 0755);
  GeneratorRun run;
  Bus bus(url);
  bus.Subscribe<labels>(
      kLabelsChannel, [&run](const labels& message) { run.scenes[message.header.seq] = message; });
  bus.Subscribe<scene>(kSceneChannel, [&run](const scene& message) {
    scene copy = message;
    copy.header.utime = 0;
    run.arrived.push_back(copy.header.seq);
    std::vector<unsigned char>& bytes = run.whole[copy.header.seq];
    bytes.resize(copy.getEncodedSize());
    copy.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  });
  std::vector<std::string> args = {std::string(STACKGEN_BIN_DIR) + "/stackgen",
                                   "--config",
                                   config,
                                   "--count",
                                   std::to_string(count),
                                   "--seed",
                                   std::to_string(seed),
                                   "--lcm-url",
                                   url,
                                   "--cache-dir",
                                   dir + "/cache",
                                   "--no-consumer-ok"};
  args.insert(args.end(), flags.begin(), flags.end());
  Process generator(args, dir + "/stackgen");

  // the labels arrive as the scenes are made; generous time for a slow machine, none once the
  // generator has exited (what it sent before is read first)
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(5);
  const auto missing = [&run, count] {
    return static_cast<int>(run.scenes.size()) < count ||
           static_cast<int>(run.whole.size()) < count;
  };
  int after_exit = 0;
  while (missing() && std::chrono::steady_clock::now() < deadline && after_exit < 5) {
    if (generator.Exited()) ++after_exit;
    bus.HandleFor(100);
  }
  run.exit_code = generator.Wait(60);
  run.output = generator.Stdout() + generator.Stderr();
  return run;
}

// Writes a config of `count` corner connectors in the default bin, then `rest` (config text), to
// `path`; returns the path.
std::string WriteConnectorConfig(const std::string& path, int count, const std::string& rest) {
  std::ofstream out(path);
  out << "part { mesh: \"" << STACKGEN_SOURCE_DIR
      << "/config/models/corner_connector.obj\" collision_mesh: \"" << STACKGEN_SOURCE_DIR
      << "/config/models/corner_connector_collision.obj\" class_name: \"connector\" count: "
      << count << " }\n"
      << "bin { inner_length_mm: 200 inner_width_mm: 150 inner_height_mm: 100 "
         "wall_thickness_mm: 8 }\n"
      << rest;
  return path;
}

// The pose fields of every instance of a scene, as raw bytes.
std::vector<unsigned char> PoseBytes(const labels& scene) {
  std::vector<unsigned char> bytes;
  const auto append = [&bytes](const void* data, size_t size) {
    const auto* begin = static_cast<const unsigned char*>(data);
    bytes.insert(bytes.end(), begin, begin + size);
  };
  for (const instance& object : scene.instances) {
    for (const pose* p : {&object.world_from_object, &object.camera_from_object}) {
      append(p->rotation, sizeof(p->rotation));
      append(p->translation_mm, sizeof(p->translation_mm));
      append(p->quaternion_wxyz, sizeof(p->quaternion_wxyz));
    }
  }
  return bytes;
}

// Two processes given the same seed publish bit-identical poses for every scene, and the same
// scenes byte for byte (images and labels), one settling its piles on one physics thread and
// encoding its scenes on one thread, the other with three of each (publishing in seq order all
// the same); a third given another seed publishes different ones.
TEST(DeterminismTest, SameSeedGivesBitIdenticalPosesAcrossProcesses) {
  const std::string dir = testing::MakeTempDir("stackgen-determinism");
  const std::string config = std::string(STACKGEN_SOURCE_DIR) + "/config/default.pbtxt";
  const GeneratorRun first = Generate(dir + "/a", 21, config, kScenes,
                                      {"--physics-threads", "1", "--encode-threads", "1"});
  const GeneratorRun second = Generate(dir + "/b", 21, config, kScenes,
                                       {"--physics-threads", "3", "--encode-threads", "3"});
  const GeneratorRun other = Generate(dir + "/c", 22);
  for (const GeneratorRun* run : {&first, &second, &other}) {
    ASSERT_EQ(run->exit_code, 0) << run->output;
    ASSERT_EQ(run->scenes.size(), static_cast<size_t>(kScenes)) << run->output;
    ASSERT_EQ(run->whole.size(), static_cast<size_t>(kScenes)) << run->output;
  }
  EXPECT_TRUE(std::is_sorted(second.arrived.begin(), second.arrived.end()) &&
              std::adjacent_find(second.arrived.begin(), second.arrived.end()) ==
                  second.arrived.end())
      << "the scenes of 3 encoding threads arrived out of seq order";

  for (int64_t seq = 0; seq < kScenes; ++seq) {
    ASSERT_EQ(first.scenes.count(seq), 1u) << "scene " << seq;
    const labels& a = first.scenes.at(seq);
    const labels& b = second.scenes.at(seq);
    const labels& c = other.scenes.at(seq);
    ASSERT_GT(a.num_instances, 0) << "scene " << seq;
    EXPECT_EQ(a.header.seed, b.header.seed) << "scene " << seq;
    EXPECT_NE(a.header.seed, c.header.seed) << "scene " << seq;

    // the same seed: every pose double is the same bit pattern
    ASSERT_EQ(a.num_instances, b.num_instances) << "scene " << seq;
    for (int i = 0; i < a.num_instances; ++i) {
      const pose& pa = a.instances[i].world_from_object;
      const pose& pb = b.instances[i].world_from_object;
      EXPECT_EQ(std::memcmp(pa.rotation, pb.rotation, sizeof(pa.rotation)), 0)
          << "scene " << seq << ", instance " << i;
      EXPECT_EQ(std::memcmp(pa.translation_mm, pb.translation_mm, sizeof(pa.translation_mm)), 0)
          << "scene " << seq << ", instance " << i;
    }
    EXPECT_TRUE(PoseBytes(a) == PoseBytes(b)) << "scene " << seq;
    EXPECT_TRUE(first.whole.at(seq) == second.whole.at(seq))
        << "scene " << seq << " differs with 3 physics and 3 encoding threads";
    EXPECT_FALSE(first.whole.at(seq) == other.whole.at(seq)) << "scene " << seq;

    // another seed: other poses
    EXPECT_FALSE(PoseBytes(a) == PoseBytes(c)) << "scene " << seq;
    const int common = std::min(a.num_instances, c.num_instances);
    int same_translation = 0;
    for (int i = 0; i < common; ++i) {
      const pose& pa = a.instances[i].world_from_object;
      const pose& pc = c.instances[i].world_from_object;
      if (std::memcmp(pa.translation_mm, pc.translation_mm, sizeof(pa.translation_mm)) == 0) {
        ++same_translation;
      }
    }
    EXPECT_EQ(same_translation, 0) << "scene " << seq;
  }
  std::cout << kScenes
            << " scenes from seed 21 twice and seed 22 once: " << first.scenes.at(0).num_instances
            << " instances in scene 0\n";
  std::filesystem::remove_all(dir);
}

// A run that starts inside a pile (views_per_pile 4, --first-seq 5: seqs 5-7 show pile 1, seq 8
// starts pile 2) with two physics and two encoding threads publishes the scenes it was asked
// for, the same as with one of each.
TEST(DeterminismTest, PhysicsThreadsFromInsideAPile) {
  const std::string dir = testing::MakeTempDir("stackgen-inside");
  const std::string config = WriteConnectorConfig(
      dir + "/views.pbtxt", 4,
      "camera { width: 160 height: 120 fx: 200 fy: 200 }\n"
      "physics { views_per_pile: 4 settle_translation_mm: 1 settle_rotation_deg: 1 "
      "settle_window_s: 0.25 }\n");
  const std::vector<std::string> from_5 = {"--first-seq", "5"};
  std::vector<std::string> two = from_5, one = from_5;
  two.insert(two.end(), {"--physics-threads", "2", "--encode-threads", "2"});
  one.insert(one.end(), {"--physics-threads", "1"});
  const GeneratorRun a = Generate(dir + "/a", 3, config, 4, two);
  const GeneratorRun b = Generate(dir + "/b", 3, config, 4, one);
  ASSERT_EQ(a.exit_code, 0) << a.output;
  ASSERT_EQ(b.exit_code, 0) << b.output;
  ASSERT_EQ(a.whole.size(), 4u) << a.output;
  for (int64_t seq = 5; seq <= 8; ++seq) {
    ASSERT_EQ(a.whole.count(seq), 1u) << "scene " << seq << "\n" << a.output;
    EXPECT_TRUE(a.whole.at(seq) == b.whole.at(seq)) << "scene " << seq;
  }
  std::filesystem::remove_all(dir);
}

// The program's pipeline with pick sequences: piles of 3 parts show 3, 2, 1 and 0 parts in
// scenes 0-3 and again in 4-7 (the next pile settles while a state is shown and picks are made
// one after the other), and the states of a pile share no camera seed.
TEST(DeterminismTest, PickSequenceEmptiesEachPileInTurn) {
  const std::string dir = testing::MakeTempDir("stackgen-picks");
  const std::string config =
      WriteConnectorConfig(dir + "/picks.pbtxt", 3, "physics { pick_sequence: true }\n");
  const GeneratorRun run = Generate(dir + "/a", 5, config, 8);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  ASSERT_EQ(run.scenes.size(), 8u) << run.output;
  std::vector<int> counts;
  std::set<int64_t> seeds;
  for (const auto& [seq, scene] : run.scenes) {
    counts.push_back(scene.num_instances);
    seeds.insert(scene.header.seed);
  }
  EXPECT_EQ(counts, (std::vector<int>{3, 2, 1, 0, 3, 2, 1, 0}));
  EXPECT_EQ(seeds.size(), 8u);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace stackgen
