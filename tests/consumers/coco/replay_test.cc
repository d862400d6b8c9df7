// Replays a recorded LCM log (tests/fixtures/logs/tiny.lcmlog, made by tools/make-fixture-logs)
// into stackgen-coco, read straight from the file and played onto a private multicast bus by the
// stock lcm-logplayer: no generator and no renderer run. Both datasets must hold exactly the
// labels of the log, and be the same.

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <stackgen/scene.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/log.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::FindOnPath;
using testing::Process;
using testing::ScratchDir;

const std::string kCoco = std::string(STACKGEN_BIN_DIR) + "/stackgen-coco";
const std::string kLog = std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/logs/tiny.lcmlog";

// the scenes of a fixture log, in log order; on failure `error` says what is wrong and how to
// fix it (a log recorded before a change to types/*.lcm no longer decodes)
std::vector<scene> FixtureScenes(const std::string& path, std::string* error) {
  std::vector<scene> scenes;
  try {
    ReadLog(path, [&](const LogEvent& event) {
      if (event.channel == kSceneChannel) scenes.push_back(DecodeLogEvent<scene>(event));
    });
  } catch (const DecodeError& decode_error) {
    *error = "fixture log " + path +
             " does not decode as stackgen.scene: regenerate with tools/make-fixture-logs (" +
             decode_error.what() + ")";
  } catch (const std::exception& read_error) {
    *error = "cannot read fixture log " + path + ": " + read_error.what();
  }
  if (error->empty() && scenes.empty()) *error = "fixture log " + path + " holds no scene";
  return scenes;
}

// the annotations.json of a dataset folder
json ReadDataset(const std::string& dir) {
  const std::string path = dir + "/annotations.json";
  if (!fs::exists(path)) return json();
  return json::parse(testing::ReadFile(path));
}

// checks that `dataset` holds one image per scene of the log and, per image, one annotation per
// annotated (iscrowd 0) or ignored (iscrowd 1) instance, with the log's id, box, pixel count and
// visible mask
void ExpectMatchesLog(const json& dataset, const std::vector<scene>& scenes) {
  ASSERT_TRUE(dataset.is_object()) << "no annotations.json";
  ASSERT_EQ(dataset["images"].size(), scenes.size());
  std::map<int64_t, const json*> images;  // by image id
  for (const json& image : dataset["images"]) images[image["id"].get<int64_t>()] = &image;
  std::map<int64_t, std::map<int, const json*>> annotations;  // by image id, then instance id
  for (const json& annotation : dataset["annotations"]) {
    annotations[annotation["image_id"].get<int64_t>()][annotation["instance_id"].get<int>()] =
        &annotation;
  }

  size_t expected_annotations = 0, with_grasps = 0, with_jaws = 0, proven = 0;
  for (const scene& logged : scenes) {
    // the image: its id is generator_id * 1e8 + seq + 1 (consumers/coco/coco_writer.h)
    const int64_t id = int64_t{logged.header.generator_id} * 100000000 + logged.header.seq + 1;
    SCOPED_TRACE("log scene generator " + std::to_string(logged.header.generator_id) + " seq " +
                 std::to_string(logged.header.seq));
    ASSERT_EQ(images.count(id), 1u);
    const json& image = *images[id];
    EXPECT_EQ(image["width"], logged.camera.width);
    EXPECT_EQ(image["height"], logged.camera.height);
    EXPECT_EQ(image["stackgen"]["seq"], logged.header.seq);
    EXPECT_EQ(image["stackgen"]["seed"], logged.header.seed);

    // its annotations: the annotated and the ignored instances, nothing else
    std::set<int> expected_ids;
    for (const instance& object : logged.instances) {
      if (!object.annotated && !object.ignored) continue;
      expected_ids.insert(object.instance_id);
      SCOPED_TRACE("instance " + std::to_string(object.instance_id));
      ASSERT_EQ(annotations[id].count(object.instance_id), 1u);
      const json& annotation = *annotations[id][object.instance_id];
      EXPECT_EQ(annotation["iscrowd"], object.ignored ? 1 : 0);
      EXPECT_EQ(annotation["area"], object.px_count_visib);
      EXPECT_EQ(annotation["px_count_all"], object.px_count_all);
      EXPECT_EQ(annotation["segmentation"]["counts"], object.mask_visib_rle);
      EXPECT_EQ(annotation["bbox"],
                json(std::vector<int>(object.bbox_visib, object.bbox_visib + 4)));
      // its grasps (annotated instances only) in the "stackgen" block, by rank, each the log's
      std::vector<const suction_grasp*> grasps;
      for (const suction_grasp& grasp : logged.suction_grasps) {
        if (grasp.instance_id == object.instance_id) grasps.push_back(&grasp);
      }
      size_t jaws = 0;
      for (const jaw_grasp& grasp : logged.jaw_grasps) {
        if (grasp.instance_id != object.instance_id) continue;
        ++jaws;
        const json& record = annotation["stackgen"]["parallel_jaw_grasps"].at(
            static_cast<size_t>(grasp.rank));
        EXPECT_EQ(record["width_mm"], grasp.width_mm);
        EXPECT_EQ(record["point_b_mm"],
                  json(std::vector<double>(grasp.point_b_mm, grasp.point_b_mm + 3)));
      }
      if (jaws > 0) EXPECT_EQ(annotation["stackgen"]["parallel_jaw_grasps"].size(), jaws);
      if (grasps.empty() && jaws == 0) {
        EXPECT_FALSE(annotation.contains("stackgen"));
        continue;
      }
      if (grasps.empty()) continue;
      const json& stored = annotation["stackgen"]["suction_grasps"];
      ASSERT_EQ(stored.size(), grasps.size());
      for (const suction_grasp* grasp : grasps) {
        const json& record = stored.at(static_cast<size_t>(grasp->rank));
        EXPECT_EQ(record["rank"], grasp->rank);
        EXPECT_EQ(record["u"], grasp->u);
        EXPECT_EQ(record["seal"], grasp->seal);
        EXPECT_EQ(record["approach_clear"], grasp->approach_clear != 0);
        EXPECT_EQ(record["point_mm"],
                  json(std::vector<double>(grasp->point_mm, grasp->point_mm + 3)));
        EXPECT_EQ(record.contains("moved_instance_ids"),
                  grasp->proof != suction_grasp::PROOF_NOT_TRIED);
      }
    }
    EXPECT_EQ(annotations[id].size(), expected_ids.size());
    expected_annotations += expected_ids.size();
    for (const suction_grasp& grasp : logged.suction_grasps) {
      proven += grasp.proof != suction_grasp::PROOF_NOT_TRIED;
      with_grasps += grasp.rank == 0;
    }
    for (const jaw_grasp& grasp : logged.jaw_grasps) with_jaws += grasp.rank == 0;
  }
  EXPECT_EQ(dataset["annotations"].size(), expected_annotations);
  // the fixture's config labels grasps and proves the top part's best one in every scene
  EXPECT_GT(with_grasps, scenes.size());
  EXPECT_GT(with_jaws, scenes.size());
  EXPECT_EQ(proven, scenes.size());
}

// the image files of a dataset: name -> bytes
std::map<std::string, std::string> ImageFiles(const std::string& dir) {
  std::map<std::string, std::string> files;
  if (!fs::is_directory(dir + "/images")) return files;
  for (const auto& entry : fs::directory_iterator(dir + "/images")) {
    files[entry.path().filename().string()] = testing::ReadFile(entry.path().string());
  }
  return files;
}

// runs stackgen-coco on the log itself (file://LOG?speed=0), with no --count: it stops at the
// end of the log; returns its exit code
int ReplayFromFile(const std::string& out, const std::string& log_prefix, std::string* output) {
  // the fixture log was recorded on an open bus (no key): it is read with --open-bus
  Process coco({kCoco, "--lcm-url", "file://" + kLog + "?speed=0", "--out", out, "--open-bus"},
               log_prefix);
  const int code = coco.Wait(120);
  *output = coco.Stdout() + coco.Stderr();
  return code;
}

// Read straight from the log (file://LOG?speed=0), stackgen-coco writes one image per logged
// scene and exactly the logged labels as annotations, and exits 0 at the end of the log.
TEST(CocoReplayTest, FileReplayMatchesTheLog) {
  std::string error;
  const std::vector<scene> scenes = FixtureScenes(kLog, &error);
  ASSERT_TRUE(error.empty()) << error;
  const ScratchDir scratch("coco-replay");
  const std::string out = scratch.path() + "/file";

  std::string output;
  EXPECT_EQ(ReplayFromFile(out, scratch.path() + "/file", &output), 0) << output;
  ExpectMatchesLog(ReadDataset(out), scenes);
  EXPECT_EQ(ImageFiles(out).size(), scenes.size());
}

// The same log played onto a private multicast bus by lcm-logplayer, into a live stackgen-coco,
// gives the labels of the log and the same annotations.json, byte for byte, and images as the
// file replay.
TEST(CocoReplayTest, LogplayerReplayMatchesFileReplay) {
  const std::string logplayer = FindOnPath("lcm-logplayer");
  if (logplayer.empty()) GTEST_SKIP() << "lcm-logplayer not on PATH (Debian package liblcm-bin)";
  std::string error;
  const std::vector<scene> scenes = FixtureScenes(kLog, &error);
  ASSERT_TRUE(error.empty()) << error;
  const ScratchDir scratch("coco-replay");

  // live: the writer listens first, then the log is played at its recorded pace
  const std::string live = scratch.path() + "/live";
  const std::string url = testing::FreeMulticastUrl();
  Process coco({kCoco, "--lcm-url", url, "--count", std::to_string(scenes.size()), "--out", live,
                "--open-bus"},
               scratch.path() + "/coco");
  ASSERT_TRUE(coco.WaitForOutput("listening", 30)) << coco.Stderr();
  Process player({logplayer, "--lcm-url", url, kLog}, scratch.path() + "/logplayer");
  ASSERT_EQ(player.Wait(120), 0) << player.Stderr();
  ASSERT_EQ(coco.Wait(60), 0) << coco.Stdout() << coco.Stderr();
  ExpectMatchesLog(ReadDataset(live), scenes);

  // from the file: the same dataset
  const std::string file = scratch.path() + "/file";
  std::string output;
  ReplayFromFile(file, scratch.path() + "/file", &output);
  ASSERT_TRUE(fs::exists(file + "/annotations.json"))
      << "file replay wrote no annotations.json: " << output;
  EXPECT_EQ(testing::ReadFile(live + "/annotations.json"),
            testing::ReadFile(file + "/annotations.json"));
  EXPECT_EQ(ImageFiles(live), ImageFiles(file));
}

}  // namespace
}  // namespace stackgen
