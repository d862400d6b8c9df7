// Reading datasets for stackgen-stats (tools/stats/dataset.h): postures in a reference frame,
// the angle about the vertical, a real COCO file, and LCM logs through bus/log.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <stackgen/labels.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/log.h"
#include "gen/annotate/pose.h"
#include "tests/support/process.h"
#include "tools/stats/dataset.h"

namespace stackgen::stats {
namespace {

namespace fs = std::filesystem;
using testing::ScratchDir;

const std::string kRealCoco =
    std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/stats/coco_4_scenes.json";

Eigen::Matrix3d Rz(double deg) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}
Eigen::Matrix3d AboutAxis(double deg, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, axis.normalized()).toRotationMatrix();
}

// The heading is the turn about the vertical left after any tilt about a horizontal axis, and
// undefined for a half-turn tilt.
TEST(StatsDatasetTest, HeadingIsTheTwistAboutVertical) {
  for (const double heading : {-170.0, -90.0, 0.0, 45.0, 179.0}) {
    EXPECT_NEAR(HeadingDeg(Rz(heading)), heading, 1e-9);
    for (const Eigen::Vector3d& axis :
         {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0), Eigen::Vector3d(1, -2, 0)}) {
      EXPECT_NEAR(HeadingDeg(Rz(heading) * AboutAxis(90.0, axis)), heading, 1e-9);
      EXPECT_NEAR(HeadingDeg(Rz(heading) * AboutAxis(-35.0, axis)), heading, 1e-9);
    }
  }
  EXPECT_NEAR(HeadingDeg(Rz(180.0)), 180.0, 1e-9);
  EXPECT_TRUE(std::isnan(HeadingDeg(AboutAxis(180.0, Eigen::Vector3d(1, 1, 0)))));
}

// The posture is that of world_R_object * object_R_reference; the identity keeps the mesh
// frame's angles, as written in posture_deg.
TEST(StatsDatasetTest, PostureInReferenceFrame) {
  const Eigen::Matrix3d world_R_object = RotationFromPostureDeg(Eigen::Vector3d(30, -20, 110));
  const PostureSample plain = PostureOf(world_R_object, Eigen::Matrix3d::Identity());
  EXPECT_NEAR(plain.alpha_deg, 30.0, 1e-9);
  EXPECT_NEAR(plain.beta_deg, -20.0, 1e-9);
  EXPECT_NEAR(plain.gamma_deg, 110.0, 1e-9);
  const Eigen::Matrix3d object_R_reference = RotationFromPostureDeg(Eigen::Vector3d(0, 0, -110));
  const PostureSample turned = PostureOf(world_R_object, object_R_reference);
  EXPECT_NEAR(turned.alpha_deg, 30.0, 1e-9);
  EXPECT_NEAR(turned.beta_deg, -20.0, 1e-9);
  EXPECT_NEAR(turned.gamma_deg, 0.0, 1e-9);
}

// A real stackgen-coco file: every annotation is read, and the angles recomputed from
// world_R_m2w equal the posture_deg the generator wrote.
TEST(StatsDatasetTest, ReadsRealCocoFile) {
  const Dataset dataset = ReadDataset(kRealCoco, {});
  nlohmann::json root = nlohmann::json::parse(std::ifstream(kRealCoco));
  ASSERT_EQ(dataset.samples.size(), root["annotations"].size());
  EXPECT_EQ(dataset.kind, "COCO");
  EXPECT_EQ(dataset.scenes, 4);
  EXPECT_EQ(dataset.class_counts.at("corner_connector"), 30);
  for (size_t k = 0; k < dataset.samples.size(); ++k) {
    const nlohmann::json& annotation = root["annotations"][k];
    EXPECT_NEAR(dataset.samples[k].alpha_deg, annotation["posture_deg"][0].get<double>(), 1e-9);
    EXPECT_NEAR(dataset.samples[k].beta_deg, annotation["posture_deg"][1].get<double>(), 1e-9);
    EXPECT_NEAR(dataset.samples[k].gamma_deg, annotation["posture_deg"][2].get<double>(), 1e-9);
    EXPECT_EQ(dataset.samples[k].resting_face, annotation["resting_face"].get<int>());
  }
}

// COCO ignore regions (iscrowd 1) are left out and counted as not annotated, unless
// all_instances asks for them.
TEST(StatsDatasetTest, CocoIgnoreRegionsOnlyWithAllInstances) {
  const ScratchDir scratch;
  const std::string path = scratch.path() + "/annotations.json";
  std::ofstream(path) << R"({"images": [{"id": 1, "file_name": "0_000000.png"}],
    "categories": [{"id": 1, "name": "corner_connector"}],
    "annotations": [
      {"id": 1001, "image_id": 1, "category_id": 1, "iscrowd": 0, "posture_deg": [10, 0, 0]},
      {"id": 1002, "image_id": 1, "category_id": 1, "iscrowd": 1, "posture_deg": [20, 0, 0]},
      {"id": 1003, "image_id": 1, "category_id": 1, "posture_deg": [30, 0, 0]}]})";
  const Dataset annotated = ReadDataset(path, {});
  ASSERT_EQ(annotated.samples.size(), 2u);
  EXPECT_NEAR(annotated.samples[0].alpha_deg, 10.0, 1e-9);
  EXPECT_NEAR(annotated.samples[1].alpha_deg, 30.0, 1e-9);
  EXPECT_EQ(annotated.not_annotated, 1);
  ReadOptions all;
  all.all_instances = true;
  const Dataset every = ReadDataset(path, all);
  ASSERT_EQ(every.samples.size(), 3u);
  EXPECT_NEAR(every.samples[1].alpha_deg, 20.0, 1e-9);
  EXPECT_EQ(every.not_annotated, 0);
}

// A log recorded with a bus key is read with it: labels signed with another key or not signed
// (sent by strangers while it was recorded) are left out.
TEST(StatsDatasetTest, SignedLogLeavesOutForgeries) {
  const char* key = std::getenv("STACKGEN_BUS_KEY_FILE");
  ASSERT_NE(key, nullptr) << "the suite runs with a bus key (tests/CMakeLists.txt)";
  const ScratchDir scratch;
  const std::string other_key = scratch.path() + "/other.key";
  std::ofstream(other_key) << "a stranger's key, 32 bytes or more of it\n";
  fs::permissions(other_key, fs::perms::owner_read | fs::perms::owner_write);
  const std::string path = scratch.path() + "/signed.lcmlog";
  {
    LogAppender ours(path, key);
    LogAppender theirs(path, other_key);
    LogAppender unsigned_log(path, "");
    for (int64_t seq = 0; seq < 3; ++seq) {
      stackgen::labels labels{};
      labels.header.seq = seq;
      labels.num_instances = 1;
      stackgen::instance instance{};
      instance.class_name = "corner_connector";
      instance.world_from_object = ToPoseMessage(Eigen::Isometry3d::Identity());
      instance.annotated = true;
      labels.instances.push_back(instance);
      const std::vector<uint8_t> bytes = EncodeMessage(labels);
      ours.AppendBytes(kLabelsChannel, bytes.data(), bytes.size(), 100 + seq);
      // the forgeries claim other scenes
      labels.header.seq = 10 + seq;
      const std::vector<uint8_t> forged = EncodeMessage(labels);
      theirs.AppendBytes(kLabelsChannel, forged.data(), forged.size(), 100 + seq);
      unsigned_log.AppendBytes(kLabelsChannel, forged.data(), forged.size(), 100 + seq);
    }
  }
  const Dataset dataset = ReadDataset(path, {});
  EXPECT_EQ(dataset.scenes, 3);
  EXPECT_EQ(dataset.samples.size(), 3u);
}

// A log: instances of every labels message, other channels skipped, a truncated last event
// ignored and reported; a corrupt header is an error naming the file and byte.
TEST(StatsDatasetTest, ReadsLcmLog) {
  // LogWriter writes unsigned events: read without the suite's bus key
  const testing::ScopedEnv no_key("STACKGEN_BUS_KEY_FILE", nullptr);
  const ScratchDir scratch;
  const std::string path = scratch.path() + "/run.lcmlog";
  {
    LogWriter log(path);
    for (int64_t seq = 0; seq < 3; ++seq) {
      stackgen::labels labels{};
      labels.header.seq = seq;
      labels.num_instances = 2;
      for (int k = 0; k < 2; ++k) {
        stackgen::instance instance{};
        instance.class_name = "corner_connector";
        Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
        pose.linear() = Rz(10.0 * seq + k);
        instance.world_from_object = ToPoseMessage(pose);
        instance.resting_face = k;
        instance.annotated = true;
        labels.instances.push_back(instance);
      }
      log.Write(kLabelsChannel, labels, 100 + seq);
      log.Write(kStatusChannel, labels.header, 100 + seq);
    }
  }
  ASSERT_TRUE(IsLcmLog(path));
  const Dataset whole = ReadDataset(path, {});
  EXPECT_EQ(whole.kind, "LCM log");
  EXPECT_EQ(whole.scenes, 3);
  ASSERT_EQ(whole.samples.size(), 6u);
  EXPECT_NEAR(whole.samples[5].alpha_deg, 21.0, 1e-9);
  EXPECT_EQ(whole.truncated_bytes, 0);

  // cut into the last event: the first events stay
  const auto size = fs::file_size(path);
  fs::resize_file(path, size - 7);
  const Dataset cut = ReadDataset(path, {});
  EXPECT_EQ(cut.samples.size(), 6u);  // the cut event was a status message
  EXPECT_GT(cut.truncated_bytes, 0);

  // a corrupt header in the middle: the channel length of the second event made negative
  std::string bytes = testing::ReadFile(path);
  const std::string magic = "\xED\xA1\xDA\x01";
  const size_t second = bytes.find(magic, 1);
  ASSERT_NE(second, std::string::npos);
  bytes[second + 20] = '\xFF';
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
  try {
    ReadDataset(path, {});
    FAIL() << "a corrupt log was read";
  } catch (const std::runtime_error& error) {
    EXPECT_EQ(std::string(error.what()),
              path + ": corrupt LCM log at byte " + std::to_string(second) +
                  " (event 1): channel length " + std::to_string(int32_t(0xFF000000u | 15)));
  }
}

}  // namespace
}  // namespace stackgen::stats
