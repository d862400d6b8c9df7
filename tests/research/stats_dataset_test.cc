// Reading datasets for stackgen-stats (research/stats/dataset.h): postures in a reference frame,
// the angle about the vertical, a real COCO file, LCM logs through bus/log, and BOP datasets
// (one written by stackgen-bop from the fixture log, hand-made ones).

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
#include "tests/support/bop_fixture.h"
#include "research/stats/dataset.h"

namespace stackgen::stats {
namespace {

namespace fs = std::filesystem;

// the rotation world_R_reference = Rz(alpha) Ry(beta) Rx(gamma) of a sample's posture
Eigen::Matrix3d PostureRotation(const PostureSample& s) {
  const double to_rad = M_PI / 180;
  return (Eigen::AngleAxisd(s.alpha_deg * to_rad, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(s.beta_deg * to_rad, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(s.gamma_deg * to_rad, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}
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
  // read with the stranger's key the log is no dataset: one line naming both key ids
  ReadOptions theirs_only;
  theirs_only.bus_key_file = scratch.path() + "/third.key";
  std::ofstream(theirs_only.bus_key_file) << "a third key, also 32 bytes or more of it\n";
  fs::permissions(theirs_only.bus_key_file, fs::perms::owner_read | fs::perms::owner_write);
  try {
    ReadDataset(path, theirs_only);
    FAIL() << "a log of other keys was read";
  } catch (const std::runtime_error& error) {
    const std::string text = error.what();
    EXPECT_NE(text.find("signed with another bus key"), std::string::npos) << text;
    EXPECT_EQ(text.find('\n'), std::string::npos) << text;
  }
}

// A log: instances of every labels message, other channels skipped, a truncated last event
// ignored and reported; a corrupt header is an error naming the file and byte.
TEST(StatsDatasetTest, ReadsLcmLog) {
  // LogWriter writes unsigned events: read as a log of an open bus
  ReadOptions open;
  open.open_bus = true;
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
  const Dataset whole = ReadDataset(path, open);
  EXPECT_EQ(whole.kind, "LCM log");
  EXPECT_EQ(whole.scenes, 3);
  ASSERT_EQ(whole.samples.size(), 6u);
  EXPECT_NEAR(whole.samples[5].alpha_deg, 21.0, 1e-9);
  EXPECT_EQ(whole.truncated_bytes, 0);

  // cut into the last event: the first events stay
  const auto size = fs::file_size(path);
  fs::resize_file(path, size - 7);
  const Dataset cut = ReadDataset(path, open);
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
    ReadDataset(path, open);
    FAIL() << "a corrupt log was read";
  } catch (const std::runtime_error& error) {
    EXPECT_EQ(std::string(error.what()),
              path + ": corrupt LCM log at byte " + std::to_string(second) +
                  " (event 1): channel length " + std::to_string(int32_t(0xFF000000u | 15)));
  }
}

// The BOP dataset stackgen-bop writes from the fixture log gives what the log itself gives: the
// same instances in the same order with the same class names, scenes and piles, alpha, beta,
// gamma, heading and position within 1e-9; annotated ones (visib_fract >= 0.3, the log's rule)
// by default and every instance with all_instances. BOP has no resting faces.
TEST(StatsDatasetTest, BopReadsLikeTheLog) {
  const ScratchDir scratch;
  const std::string bop = scratch.path() + "/bop";
  std::string output;
  ASSERT_EQ(testing::MakeFixtureBop(bop, scratch.path() + "/bop", &output), 0) << output;
  for (const bool all_instances : {false, true}) {
    SCOPED_TRACE(all_instances ? "all instances" : "annotated");
    ReadOptions options;
    options.all_instances = all_instances;
    options.open_bus = true;  // the log was recorded on an open bus
    const Dataset log = ReadDataset(testing::kFixtureLog, options);
    const Dataset read = ReadDataset(bop, options);
    EXPECT_EQ(read.kind, "BOP");
    EXPECT_EQ(read.split, "train_pbr");
    EXPECT_EQ(read.scenes, log.scenes);
    EXPECT_EQ(read.piles, log.piles);
    EXPECT_EQ(read.not_annotated, log.not_annotated);
    EXPECT_EQ(read.class_counts, log.class_counts);
    if (!all_instances) {
      EXPECT_GT(log.not_annotated, 0) << "the fixture has hidden instances";
    }
    ASSERT_EQ(read.samples.size(), log.samples.size());
    for (size_t k = 0; k < read.samples.size(); ++k) {
      const PostureSample& a = read.samples[k];
      const PostureSample& b = log.samples[k];
      EXPECT_EQ(a.class_name, b.class_name) << k;
      EXPECT_EQ(a.scene, b.scene) << k;
      // the same posture: alpha and gamma alone are ill-conditioned near beta = +-90 degrees (a
      // part on its side), where only their sum or difference is defined
      EXPECT_NEAR(a.beta_deg, b.beta_deg, 1e-9) << k;
      EXPECT_LT((PostureRotation(a) - PostureRotation(b)).cwiseAbs().maxCoeff(), 1e-12) << k;
      EXPECT_NEAR(a.heading_deg, b.heading_deg, 1e-9) << k;
      EXPECT_LT((a.world_position_mm - b.world_position_mm).cwiseAbs().maxCoeff(), 1e-9) << k;
      EXPECT_EQ(a.resting_face, -1) << k;
    }
  }
}

// a hand-made BOP dataset in `dir`/train_pbr/000000: image k shows the parts at `world_poses[k]`
// from camera `cameras[k]` (world_from_camera), every part visib_fract 0.9 but the first of each
// image 0.1; no scene_gt_coco.json
void WriteBop(const std::string& dir,
              const std::vector<std::vector<Eigen::Isometry3d>>& world_poses,
              const std::vector<Eigen::Isometry3d>& cameras) {
  const fs::path folder = fs::path(dir) / "train_pbr" / "000000";
  fs::create_directories(folder);
  nlohmann::json gt, camera, info;
  const auto row_major = [](const Eigen::Matrix3d& rotation) {
    std::vector<double> values;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) values.push_back(rotation(r, c));
    }
    return values;
  };
  for (size_t k = 0; k < world_poses.size(); ++k) {
    const std::string key = std::to_string(k);
    const Eigen::Isometry3d camera_from_world = cameras[k].inverse();
    const Eigen::Vector3d t_w2c = camera_from_world.translation();
    camera[key] = {{"cam_R_w2c", row_major(camera_from_world.linear())},
                   {"cam_t_w2c", {t_w2c.x(), t_w2c.y(), t_w2c.z()}}};
    gt[key] = nlohmann::json::array();
    info[key] = nlohmann::json::array();
    for (size_t p = 0; p < world_poses[k].size(); ++p) {
      const Eigen::Isometry3d camera_from_object = camera_from_world * world_poses[k][p];
      const Eigen::Vector3d t = camera_from_object.translation();
      gt[key].push_back({{"cam_R_m2c", row_major(camera_from_object.linear())},
                         {"cam_t_m2c", {t.x(), t.y(), t.z()}},
                         {"obj_id", 1}});
      info[key].push_back({{"px_count_visib", 100}, {"visib_fract", p == 0 ? 0.1 : 0.9}});
    }
  }
  std::ofstream(folder / "scene_gt.json") << gt.dump();
  std::ofstream(folder / "scene_camera.json") << camera.dump();
  std::ofstream(folder / "scene_gt_info.json") << info.dump();
}

// Two views of one pile in a BOP dataset, seen from two cameras, are one pile although the
// positions computed back through each camera differ in their last bits; a third image of other
// poses is a pile of its own. A ground truth less than 30 % visible counts as not annotated, and
// without scene_gt_coco.json the class is named after its model file.
TEST(StatsDatasetTest, BopViewsOfOnePileAreOnePile) {
  const ScratchDir scratch;
  std::vector<Eigen::Isometry3d> pile, other;
  for (int p = 0; p < 4; ++p) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = RotationFromPostureDeg(Eigen::Vector3d(17.3 * p - 40.1, 8.9 * p, 33.3 - p));
    pose.translation() = Eigen::Vector3d(-41.37 + 27.1 * p, 12.913 - 9.7 * p, 20.17 + 3.3 * p);
    pile.push_back(pose);
    pose.translation().z() += 5.0;
    other.push_back(pose);
  }
  std::vector<Eigen::Isometry3d> cameras;
  for (const double tilt : {0.0, 7.31, -11.9}) {
    Eigen::Isometry3d camera = Eigen::Isometry3d::Identity();
    camera.linear() = RotationFromPostureDeg(Eigen::Vector3d(3.7 * tilt, 180.0 - tilt, 1.3));
    camera.translation() = Eigen::Vector3d(1.1 * tilt, -0.7 * tilt, 452.123);
    cameras.push_back(camera);
  }
  WriteBop(scratch.path(), {pile, pile, other}, cameras);
  const Dataset dataset = ReadDataset(scratch.path(), {});
  EXPECT_EQ(dataset.kind, "BOP");
  EXPECT_EQ(dataset.scenes, 3);
  EXPECT_EQ(dataset.piles, 2);
  EXPECT_EQ(dataset.not_annotated, 3);
  ASSERT_EQ(dataset.samples.size(), 9u);
  EXPECT_EQ(dataset.class_counts.at("obj_000001"), 9);
  for (const PostureSample& sample : dataset.samples) {
    EXPECT_EQ(sample.pile, sample.scene == 2 ? 1 : 0);
  }
  // the postures of the world poses, whichever camera saw them
  const Eigen::Vector3d expected = PostureAnglesDeg(pile[1].linear());
  EXPECT_NEAR(dataset.samples[3].alpha_deg, expected[0], 1e-9);
  EXPECT_NEAR(dataset.samples[3].beta_deg, expected[1], 1e-9);
  EXPECT_NEAR(dataset.samples[3].gamma_deg, expected[2], 1e-9);
  EXPECT_LT((dataset.samples[3].world_position_mm - pile[1].translation()).norm(), 1e-9);
}

// A BOP record whose matrix is not a rotation, or an image without its camera, is an error
// naming the file, the image, the ground truth and the field.
TEST(StatsDatasetTest, BadBopRecordsNameFileAndField) {
  const ScratchDir scratch;
  WriteBop(scratch.path(), {{Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity()}},
           {Eigen::Isometry3d::Identity()});
  const fs::path folder = fs::path(scratch.path()) / "train_pbr" / "000000";
  const std::string gt_text = testing::ReadFile((folder / "scene_gt.json").string());
  nlohmann::json gt = nlohmann::json::parse(gt_text);
  gt["0"][1]["cam_R_m2c"] = {1, 0, 0, 0, 2, 0, 0, 0, 1};
  std::ofstream(folder / "scene_gt.json") << gt.dump();
  const auto error_of = [&](const ReadOptions& options) -> std::string {
    try {
      ReadDataset(scratch.path(), options);
    } catch (const std::runtime_error& error) {
      return error.what();
    }
    return "";
  };
  EXPECT_EQ(error_of({}), (folder / "scene_gt.json").string() +
                              ": image 0, gt 1: cam_R_m2c is not a rotation (|R^T R - I| = 3, "
                              "det = 2)");
  std::ofstream(folder / "scene_gt.json") << gt_text;
  std::ofstream(folder / "scene_camera.json") << "{}";
  EXPECT_EQ(error_of({}), (folder / "scene_camera.json").string() +
                              ": image 0 is missing (scene_gt.json has it)");
  // --split names a folder that is not there
  ReadOptions test_split;
  test_split.bop_split = "test";
  EXPECT_EQ(error_of(test_split), scratch.path() + " has no split folder test");
}

}  // namespace
}  // namespace stackgen::stats
