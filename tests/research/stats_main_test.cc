// Runs the stackgen-stats program as a process on small COCO files and LCM logs made here: its
// command line, the four test lines, the plots, and a log read the same as the COCO file of the
// same scenes; and on the BOP dataset stackgen-bop writes from the fixture log, read the same as
// the log.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <stackgen/labels.hpp>
#include <stackgen/scene.hpp>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/log.h"
#include "gen/annotate/pose.h"
#include "tests/support/process.h"
#include "tests/support/bop_fixture.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::Process;
using testing::ScratchDir;

const std::string kProgram = std::string(STACKGEN_BIN_DIR) + "/stackgen-stats";
const char* kPlots[] = {"scatter_beta_alpha.png", "scatter_beta_gamma.png", "histograms.png",
                        "cumulative.png", "faces.png"};

// one object of a hand-made scene
struct Object {
  std::string class_name = "corner_connector";
  double alpha = 0.0, beta = 0.0, gamma = 0.0;  // posture, degrees
  int resting_face = -1;
  bool annotated = true;
  Eigen::Vector3d position_mm{0.0, 0.0, 10.0};  // in the bin frame
};
using Scene = std::vector<Object>;

// `count` scenes of 6 objects whose angles and faces follow `shape`: 0 spread over all angles
// and faces 0..3, 1 bunched (alpha in [0, 30), beta near 20, gamma in [-90, -60), mostly face 0);
// every fourth object is not annotated
std::vector<Scene> MakeScenes(int count, int shape) {
  std::vector<Scene> scenes;
  for (int s = 0; s < count; ++s) {
    Scene scene;
    for (int k = 0; k < 6; ++k) {
      const int i = 6 * s + k;
      Object object;
      if (shape == 0) {
        object.alpha = -179.5 + std::fmod(i * 37.3, 359.0);
        object.beta = -89.0 + std::fmod(i * 23.7, 178.0);
        object.gamma = -179.5 + std::fmod(i * 71.1, 359.0);
        object.resting_face = i % 4;
      } else {
        object.alpha = std::fmod(i * 7.3, 30.0);
        object.beta = 15.0 + std::fmod(i * 3.1, 10.0);
        object.gamma = -90.0 + std::fmod(i * 11.3, 30.0);
        object.resting_face = i % 5 == 0 ? 1 : 0;
      }
      object.annotated = k % 4 != 3;
      // shape 1 lies higher and nearer the bin's centre line
      object.position_mm = shape == 0 ? Eigen::Vector3d(30.0 + 5 * k, -20.0 + s, 10.0 + 4 * k)
                                      : Eigen::Vector3d(3.0 * k, 2.0 + s, 50.0 + 4 * k);
      scene.push_back(object);
    }
    scenes.push_back(scene);
  }
  return scenes;
}

// the COCO file stackgen-coco would write for `scenes` (annotated objects only)
void WriteCoco(const std::vector<Scene>& scenes, const std::string& path) {
  json images = json::array(), annotations = json::array(), categories = json::array();
  std::map<std::string, int> class_ids;
  for (size_t s = 0; s < scenes.size(); ++s) {
    images.push_back({{"id", s + 1},
                      {"file_name", "images/0_" + std::to_string(s) + ".png"},
                      {"width", 64},
                      {"height", 48}});
    for (size_t k = 0; k < scenes[s].size(); ++k) {
      const Object& object = scenes[s][k];
      if (!object.annotated) continue;
      const auto id = class_ids.emplace(object.class_name, class_ids.size() + 1).first->second;
      const Eigen::Matrix3d rotation =
          RotationFromPostureDeg(Eigen::Vector3d(object.alpha, object.beta, object.gamma));
      std::vector<double> row_major;
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) row_major.push_back(rotation(r, c));
      }
      const Eigen::Vector3d posture = PostureAnglesDeg(rotation);
      annotations.push_back(
          {{"id", 1000 * (s + 1) + k + 1},
           {"image_id", s + 1},
           {"category_id", id},
           {"visib_fract", 0.9},
           {"posture_deg", {posture[0], posture[1], posture[2]}},
           {"resting_face", object.resting_face},
           {"world_R_m2w", row_major},
           {"world_t_m2w", {object.position_mm[0], object.position_mm[1], object.position_mm[2]}}});
    }
  }
  for (const auto& [name, id] : class_ids) {
    categories.push_back({{"id", id}, {"name", name}, {"supercategory", "part"}});
  }
  std::ofstream(path)
      << json{{"images", images}, {"categories", categories}, {"annotations", annotations}}.dump(1);
}

// the labels message of scene `seq`
stackgen::labels LabelsOf(const Scene& scene, int64_t seq) {
  stackgen::labels labels{};
  labels.header.seq = seq;
  labels.header.generator_id = 0;
  labels.num_instances = static_cast<int32_t>(scene.size());
  for (size_t k = 0; k < scene.size(); ++k) {
    const Object& object = scene[k];
    stackgen::instance instance{};
    instance.instance_id = static_cast<int32_t>(k + 1);
    instance.class_id = 1;
    instance.class_name = object.class_name;
    const Eigen::Matrix3d rotation =
        RotationFromPostureDeg(Eigen::Vector3d(object.alpha, object.beta, object.gamma));
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = rotation;
    pose.translation() = object.position_mm;
    instance.world_from_object = ToPoseMessage(pose);
    instance.camera_from_object = ToPoseMessage(pose);
    const Eigen::Vector3d posture = PostureAnglesDeg(rotation);
    for (int a = 0; a < 3; ++a) instance.posture_deg[a] = posture[a];
    instance.resting_face = object.resting_face;
    instance.annotated = object.annotated;
    instance.visib_fract = object.annotated ? 0.9 : 0.1;
    labels.instances.push_back(instance);
  }
  return labels;
}

// an LCM log of `scenes` on STACKGEN_LABELS; the first two also on STACKGEN_SCENE (counted once)
void WriteLog(const std::vector<Scene>& scenes, const std::string& path) {
  LogWriter log(path);
  for (size_t s = 0; s < scenes.size(); ++s) {
    const stackgen::labels labels = LabelsOf(scenes[s], static_cast<int64_t>(s));
    log.Write(kLabelsChannel, labels, 1000 + static_cast<int64_t>(s));
    log.Write(kStatusChannel, labels.header, 1000 + static_cast<int64_t>(s));
    if (s < 2) {
      stackgen::scene scene{};
      scene.header = labels.header;
      scene.camera = labels.camera;
      scene.num_instances = labels.num_instances;
      scene.instances = labels.instances;
      log.Write(kSceneChannel, scene, 1001 + static_cast<int64_t>(s));
    }
  }
  log.Close();
}

struct Result {
  int code = -1;
  std::string out;
  std::string err;
};

// runs stackgen-stats with `args` to the end
Result RunStats(const std::vector<std::string>& args, const std::string& log_prefix) {
  std::vector<std::string> argv = {kProgram};
  argv.insert(argv.end(), args.begin(), args.end());
  Process process(argv, log_prefix);
  Result result;
  result.code = process.Wait(60);
  result.out = process.Stdout();
  result.err = process.Stderr();
  return result;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::string line;
  for (const char c : text) {
    if (c == '\n') {
      lines.push_back(line);
      line.clear();
    } else {
      line += c;
    }
  }
  if (!line.empty()) lines.push_back(line);
  return lines;
}

// the value after `key=` in `line`
double ValueOf(const std::string& line, const std::string& key) {
  const size_t at = line.find(" " + key + "=");
  if (at == std::string::npos) return std::nan("");
  return std::stod(line.substr(at + key.size() + 2));
}

// --help documents every flag and default, the frame and the exit codes, and exits 0.
TEST(StatsMainTest, HelpListsEveryFlag) {
  const ScratchDir scratch;
  const Result result = RunStats({"--help"}, scratch.path() + "/help");
  EXPECT_EQ(result.code, 0);
  for (const char* text : {"--out",
                           "--alpha",
                           "default 0.05",
                           "--frame CLASS=RZ,RY,RX",
                           "--class",
                           "--all-instances",
                           "--help",
                           "origin",
                           "--permutations",
                           "default 999",
                           "--seed",
                           "--calibrate",
                           "Holm",
                           "permutation",
                           "Exit status",
                           "--split NAME",
                           "train_pbr",
                           "BOP",
                           "scene_gt.json",
                           "visib_fract >= 0.3",
                           "cam_R_w2c^T cam_R_m2c",
                           "obj_OBJ_ID"}) {
    EXPECT_NE(result.out.find(text), std::string::npos) << text << " missing from\n" << result.out;
  }
}

// Bad command lines give one line on stderr and exit 2.
TEST(StatsMainTest, BadCommandLineExits2) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  const std::string coco = dir + "/a.json";
  WriteCoco(MakeScenes(3, 0), coco);
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--out", dir + "/plots"},
        {coco},
        {coco, "--out", dir + "/plots", "--alpha", "1.5"},
        {coco, "--out", dir + "/plots", "--alpha", "x"},
        {coco, "--out", dir + "/plots", "--frame", "corner_connector=90,0"},
        {coco, "--out", dir + "/plots", "--frame", "90,0,0"},
        {coco, "--out", dir + "/plots", "--bogus"},
        {coco, coco, coco, "--out", dir + "/plots"},
        {coco, "--out", dir + "/plots", "--permutations", "5"},
        {coco, coco, "--out", dir + "/plots", "--calibrate", "10"}}) {
    const Result result = RunStats(args, dir + "/bad");
    EXPECT_EQ(result.code, 2) << args.back();
    EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1) << result.err;
    EXPECT_EQ(result.err.rfind("stackgen-stats: error: ", 0), 0u) << result.err;
  }
  EXPECT_FALSE(fs::exists(dir + "/plots"));
}

// Unreadable, foreign and broken datasets give one line naming the file and exit 2.
TEST(StatsMainTest, BadInputExits2) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  std::ofstream(dir + "/text.txt") << "hello\n";
  std::ofstream(dir + "/broken.json") << "{\"images\": [";
  std::ofstream(dir + "/other.json") << "{\"type\": \"not coco\"}";
  std::ofstream(dir + "/bad_rotation.json")
      << R"({"images": [{"id": 1}], "categories": [{"id": 1, "name": "part"}],
             "annotations": [{"id": 1, "image_id": 1, "category_id": 1,
                              "world_R_m2w": [1, 0, 0, 0, 2, 0, 0, 0, 1]}]})";
  {
    // the log magic and an event header with a channel length of 5000
    std::ofstream log(dir + "/garbage.log", std::ios::binary);
    const unsigned char bytes[] = {
        0xED, 0xA1, 0xDA, 0x01, 0,    0, 0, 0, 0, 0,   0,   0,   0,   0,   0,   0,   0,   0,   0,
        0,    0x00, 0x00, 0x13, 0x88, 0, 0, 0, 5, 'a', 'b', 'c', 'd', 'e', 'X', 'X', 'X', 'X', 'X'};
    log.write(reinterpret_cast<const char*>(bytes), sizeof(bytes));
  }
  {
    // a log without stackgen messages
    LogWriter log(dir + "/empty.log");
    const uint8_t byte = 0;
    log.WriteBytes("OTHER", &byte, 1, 1);
  }
  for (const char* name : {"missing.json", "text.txt", "broken.json", "other.json",
                           "bad_rotation.json", "garbage.log", "empty.log"}) {
    const std::string file = dir + "/" + name;
    const Result result = RunStats({file, "--out", dir + "/plots"}, dir + "/bad");
    EXPECT_EQ(result.code, 2) << name << ": " << result.err;
    EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1) << result.err;
    EXPECT_NE(result.err.find(file), std::string::npos) << result.err;
  }
  EXPECT_FALSE(fs::exists(dir + "/plots"));
}

// the test lines of a dataset compared with itself, then the verdict
const std::vector<std::string> kIdenticalLines = {
    "alpha: D=0 p=1 holm=1 same",
    "beta: D=0 p=1 holm=1 same",
    "gamma: D=0 p=1 holm=1 same",
    "heading: V=0 p=1 holm=1 same",
    "face: chi2=0 dof=3 p=1 holm=1 same",
    "height: D=0 p=1 holm=1 same",
    "radius: D=0 p=1 holm=1 same",
    "verdict: same (0 of 7 tests reject at 0.05 after Holm's correction)"};

// A dataset compared with itself: the seven test lines in order and format, each statistic 0,
// p = 1, "same", and the verdict.
TEST(StatsMainTest, IdenticalDatasetsAreSame) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  WriteCoco(MakeScenes(10, 0), dir + "/a.json");
  const Result result =
      RunStats({dir + "/a.json", dir + "/a.json", "--out", dir + "/plots"}, dir + "/run");
  ASSERT_EQ(result.code, 0) << result.err;
  const std::vector<std::string> lines = Lines(result.out);
  ASSERT_GE(lines.size(), kIdenticalLines.size()) << result.out;
  const std::regex test_line(
      R"((alpha|beta|gamma|heading|face|height|radius): (D|V|chi2)=\S+( dof=\d+)? p=\S+ )"
      R"(holm=\S+ (same|different))");
  for (size_t k = 0; k < kIdenticalLines.size(); ++k) {
    if (k + 1 < kIdenticalLines.size()) {
      EXPECT_TRUE(std::regex_match(lines[k], test_line)) << lines[k];
    }
    EXPECT_EQ(lines[k], kIdenticalLines[k]);
  }
  // the paper's reproduction lines and the counts follow
  EXPECT_NE(result.out.find("paper alpha: D=0 Z=0 p=1\n"), std::string::npos) << result.out;
  EXPECT_NE(result.out.find("formula (4)"), std::string::npos);
  EXPECT_NE(result.out.find("999 random reassignments of whole piles (10 of A, 10 of B)"),
            std::string::npos)
      << result.out;
  EXPECT_NE(result.out.find("50 instances of 10 images"), std::string::npos) << result.out;
  EXPECT_EQ(result.out.find(" piles: "), std::string::npos) << result.out;

  // two views of one pile (scene 3 shows scene 2's poses from elsewhere) are one pile
  std::vector<Scene> views = MakeScenes(10, 0);
  views[3] = views[2];
  WriteCoco(views, dir + "/views.json");
  const Result grouped =
      RunStats({dir + "/views.json", dir + "/a.json", "--out", dir + "/plots"}, dir + "/views");
  ASSERT_EQ(grouped.code, 0) << grouped.err;
  EXPECT_NE(grouped.out.find("(9 piles: views of one pile are permuted together)"),
            std::string::npos)
      << grouped.out;
  EXPECT_NE(grouped.out.find("(9 of A, 10 of B)"), std::string::npos) << grouped.out;
}

// Clearly different datasets: every line says "different" with small p, whatever --alpha; the
// program still exits 0.
TEST(StatsMainTest, DifferentDatasetsAreDifferent) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  WriteCoco(MakeScenes(10, 0), dir + "/a.json");
  WriteCoco(MakeScenes(10, 1), dir + "/b.json");
  const Result result = RunStats(
      {dir + "/a.json", dir + "/b.json", "--out", dir + "/plots", "--alpha", "0.01"}, dir + "/run");
  ASSERT_EQ(result.code, 0) << result.err;
  const std::vector<std::string> lines = Lines(result.out);
  ASSERT_GE(lines.size(), 8u) << result.out;
  for (const size_t k : {0, 1, 2, 4, 5, 6}) {  // all but the heading, which both spread
    EXPECT_NE(lines[k].find(" different"), std::string::npos) << lines[k];
    EXPECT_LT(ValueOf(lines[k], "holm"), 0.01) << lines[k];
  }
  EXPECT_GT(ValueOf(lines[0], "D"), 0.5) << lines[0];
  EXPECT_EQ(lines[7].rfind("verdict: different (", 0), 0u) << lines[7];
}

// The five figures exist, decode and have sensible sizes; temporary files are gone.
TEST(StatsMainTest, WritesPlots) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  WriteCoco(MakeScenes(10, 0), dir + "/a.json");
  WriteCoco(MakeScenes(10, 1), dir + "/b.json");
  const std::string plots = dir + "/deep/plots";
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{dir + "/a.json", dir + "/b.json", "--out", plots},
        {dir + "/a.json", "--out", plots}}) {
    const Result result = RunStats(args, dir + "/run");
    ASSERT_EQ(result.code, 0) << result.err;
    for (const char* name : kPlots) {
      const cv::Mat image = cv::imread(plots + "/" + name, cv::IMREAD_UNCHANGED);
      ASSERT_FALSE(image.empty()) << name;
      EXPECT_EQ(image.type(), CV_8UC3) << name;
      EXPECT_GE(image.cols, 400) << name;
      EXPECT_GE(image.rows, 400) << name;
      EXPECT_LE(image.cols, 2000) << name;
      // something besides the white background is drawn
      cv::Mat gray;
      cv::extractChannel(image, gray, 0);
      EXPECT_GT(cv::countNonZero(gray < 128), 1000) << name;
    }
    for (const auto& entry : fs::directory_iterator(plots)) {
      EXPECT_EQ(entry.path().extension(), ".png") << entry.path();
    }
  }
}

// One dataset: per-angle summaries and face frequencies, no test lines.
TEST(StatsMainTest, OneDatasetSummary) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  WriteCoco(MakeScenes(10, 1), dir + "/b.json");
  const Result result = RunStats({dir + "/b.json", "--out", dir + "/plots"}, dir + "/run");
  ASSERT_EQ(result.code, 0) << result.err;
  const std::vector<std::string> lines = Lines(result.out);
  ASSERT_GE(lines.size(), 5u);
  EXPECT_EQ(lines[0].rfind("alpha: n=50 mean=", 0), 0u) << lines[0];
  EXPECT_EQ(lines[1].rfind("beta: n=50 mean=", 0), 0u) << lines[1];
  EXPECT_EQ(lines[2].rfind("gamma: n=50 mean=", 0), 0u) << lines[2];
  EXPECT_NEAR(ValueOf(lines[1], "mean"), 20.0, 1.0) << lines[1];
  EXPECT_EQ(result.out.find(" D="), std::string::npos) << result.out;
  EXPECT_NE(result.out.find("face: 0:"), std::string::npos) << result.out;

  // --calibrate: halves of the one dataset compared, how often "different" comes first
  const Result calibrated =
      RunStats({dir + "/b.json", "--out", dir + "/plots", "--calibrate", "20"}, dir + "/cal");
  ASSERT_EQ(calibrated.code, 0) << calibrated.err;
  const std::vector<std::string> calibration = Lines(calibrated.out);
  ASSERT_GE(calibration.size(), 3u);
  EXPECT_EQ(calibration[0].rfind("calibration: 20 random splits of the 10 piles into halves: "
                                 "\"different\" in ",
                                 0),
            0u)
      << calibration[0];
  EXPECT_EQ(calibration[1].rfind("calibration per test (different): alpha ", 0), 0u)
      << calibration[1];
  EXPECT_EQ(calibration[2], lines[0]);
}

// An LCM log of labels (some scenes also on STACKGEN_SCENE, other channels mixed in) gives the
// same sample as the COCO file of the same scenes; --all-instances adds the hidden ones.
TEST(StatsMainTest, LcmLogReadsLikeCoco) {
  // the log is written unsigned: read as a log of an open bus (--open-bus)
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  const std::vector<Scene> scenes = MakeScenes(10, 0);
  WriteCoco(scenes, dir + "/a.json");
  WriteLog(scenes, dir + "/a.log");
  ASSERT_TRUE(IsLcmLog(dir + "/a.log"));

  // compared with each other: nothing differs
  const Result both = RunStats(
      {dir + "/a.log", dir + "/a.json", "--out", dir + "/plots", "--open-bus"}, dir + "/r");
  ASSERT_EQ(both.code, 0) << both.err;
  const std::vector<std::string> lines = Lines(both.out);
  ASSERT_GE(lines.size(), kIdenticalLines.size());
  for (size_t k = 0; k < kIdenticalLines.size(); ++k) EXPECT_EQ(lines[k], kIdenticalLines[k]);
  EXPECT_NE(both.out.find("(LCM log): 50 instances of 10 scenes, 10 not annotated left out, 2 "
                          "repeated scene messages skipped"),
            std::string::npos)
      << both.out;

  // the summaries agree to the last digit
  const Result log = RunStats({dir + "/a.log", "--out", dir + "/plots", "--open-bus"}, dir + "/r");
  const Result coco = RunStats({dir + "/a.json", "--out", dir + "/plots"}, dir + "/r");
  ASSERT_EQ(log.code, 0) << log.err;
  const std::vector<std::string> log_lines = Lines(log.out), coco_lines = Lines(coco.out);
  for (size_t k = 0; k < 5; ++k) EXPECT_EQ(log_lines[k], coco_lines[k]);

  // the hidden instances too
  const Result all = RunStats(
      {dir + "/a.log", "--out", dir + "/plots", "--all-instances", "--open-bus"}, dir + "/r");
  ASSERT_EQ(all.code, 0) << all.err;
  EXPECT_EQ(Lines(all.out)[0].rfind("alpha: n=60 ", 0), 0u) << all.out;
}

// --frame turns the reference frame: a quarter turn about the object's z adds 90 degrees to
// alpha of objects lying flat; --class keeps one class and refuses an absent one.
TEST(StatsMainTest, FrameAndClass) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  std::vector<Scene> scenes(1);
  for (int k = 0; k < 8; ++k) {
    Object object;
    object.alpha = -170.0 + 20.0 * k;  // -170 .. -30
    object.class_name = k < 6 ? "corner_connector" : "pin";
    scenes[0].push_back(object);
  }
  WriteCoco(scenes, dir + "/flat.json");

  const Result plain = RunStats(
      {dir + "/flat.json", "--out", dir + "/plots", "--class", "corner_connector"}, dir + "/r");
  ASSERT_EQ(plain.code, 0) << plain.err;
  EXPECT_EQ(Lines(plain.out)[0].rfind("alpha: n=6 mean=-120 ", 0), 0u) << plain.out;
  EXPECT_NE(plain.out.find("2 of other classes left out"), std::string::npos) << plain.out;

  const Result turned = RunStats({dir + "/flat.json", "--out", dir + "/plots", "--class",
                                  "corner_connector", "--frame", "corner_connector=90,0,0"},
                                 dir + "/r");
  ASSERT_EQ(turned.code, 0) << turned.err;
  EXPECT_EQ(Lines(turned.out)[0].rfind("alpha: n=6 mean=-30 ", 0), 0u) << turned.out;

  const Result pooled = RunStats({dir + "/flat.json", "--out", dir + "/plots"}, dir + "/r");
  EXPECT_NE(pooled.out.find("note: A pools 2 classes (corner_connector 6, pin 2)"),
            std::string::npos)
      << pooled.out;

  const Result absent =
      RunStats({dir + "/flat.json", "--out", dir + "/plots", "--class", "gear"}, dir + "/r");
  EXPECT_EQ(absent.code, 2);
  EXPECT_NE(absent.err.find("holds no instances of class gear"), std::string::npos) << absent.err;
}

// The BOP dataset stackgen-bop writes from the fixture log summarises like the log itself, to the
// last digit printed: the annotated ground truths (visib_fract >= 0.3) by default, all of them
// with --all-instances; the dataset line names the kind, and a note says what counts as annotated.
TEST(StatsMainTest, BopDatasetReadsLikeTheLog) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  const std::string bop = dir + "/bop";
  std::string output;
  ASSERT_EQ(testing::MakeFixtureBop(bop, dir + "/bop", &output), 0) << output;
  for (const bool all_instances : {false, true}) {
    SCOPED_TRACE(all_instances ? "--all-instances" : "annotated");
    std::vector<std::string> bop_args = {bop, "--out", dir + "/plots"};
    // the fixture log was recorded on an open bus
    std::vector<std::string> log_args = {testing::kFixtureLog, "--out", dir + "/plots",
                                         "--open-bus"};
    if (all_instances) {
      bop_args.push_back("--all-instances");
      log_args.push_back("--all-instances");
    }
    const Result from_bop = RunStats(bop_args, dir + "/bop-run");
    const Result from_log = RunStats(log_args, dir + "/log-run");
    ASSERT_EQ(from_bop.code, 0) << from_bop.err;
    ASSERT_EQ(from_log.code, 0) << from_log.err;
    // alpha, beta, gamma, heading
    const std::vector<std::string> bop_lines = Lines(from_bop.out), log_lines = Lines(from_log.out);
    ASSERT_GE(bop_lines.size(), 4u) << from_bop.out;
    ASSERT_GE(log_lines.size(), 4u) << from_log.out;
    for (size_t k = 0; k < 4; ++k) EXPECT_EQ(bop_lines[k], log_lines[k]);
    EXPECT_EQ(bop_lines[0].rfind(all_instances ? "alpha: n=24 " : "alpha: n=21 ", 0), 0u)
        << from_bop.out;
    EXPECT_NE(from_bop.out.find(all_instances ? "A: " + bop + " (BOP): 24 instances of 4 images\n"
                                              : "A: " + bop +
                                                    " (BOP): 21 instances of 4 images, 3 not "
                                                    "annotated left out\n"),
              std::string::npos)
        << from_bop.out;
    EXPECT_NE(from_bop.out.find(all_instances
                                    ? "note: A is a BOP dataset (split train_pbr): every ground "
                                      "truth is used"
                                    : "note: A is a BOP dataset (split train_pbr): a ground truth "
                                      "counts as annotated when its visib_fract >= 0.3"),
              std::string::npos)
        << from_bop.out;
  }
}

// A folder that is neither dataset, a split that is not there and bad BOP records give one line
// naming the file (and the image, ground truth and field) and exit 2.
TEST(StatsMainTest, BadBopInputExits2) {
  const ScratchDir scratch;
  const std::string dir = scratch.path();
  const auto write = [](const fs::path& path, const std::string& text) {
    fs::create_directories(path.parent_path());
    std::ofstream(path) << text;
  };
  const std::string gt =
      R"({"0": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 400], "obj_id": 1}],
          "1": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 400], "obj_id": 1}]})";
  const std::string info = R"({"0": [{"px_count_visib": 50, "visib_fract": 0.5}],
                               "1": [{"px_count_visib": 50, "visib_fract": 0.5}]})";
  // image 1 has no camera
  const std::string no_camera = dir + "/no_camera/train_pbr/000000";
  write(no_camera + "/scene_gt.json", gt);
  write(no_camera + "/scene_gt_info.json", info);
  write(no_camera + "/scene_camera.json",
        R"({"0": {"cam_R_w2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_w2c": [0, 0, 0]}})");
  // the camera of image 1 is turned and stretched
  const std::string stretched = dir + "/stretched/train_pbr/000000";
  write(stretched + "/scene_gt.json", gt);
  write(stretched + "/scene_gt_info.json", info);
  write(stretched + "/scene_camera.json",
        R"({"0": {"cam_R_w2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_w2c": [0, 0, 0]},
            "1": {"cam_R_w2c": [0, 2, 0, 1, 0, 0, 0, 0, 1], "cam_t_w2c": [0, 0, 0]}})");
  fs::create_directories(dir + "/empty");
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{dir + "/no_camera"},
       no_camera + "/scene_camera.json: image 1 is missing (scene_gt.json has it)"},
      {{dir + "/stretched"},
       stretched + "/scene_camera.json: image 1: cam_R_w2c is not a rotation (|R^T R - I| = 3, "
                   "det = -2)"},
      {{dir + "/empty"},
       dir + "/empty is a folder without annotations.json (COCO) or a BOP split folder "
             "(SPLIT/SCENE_ID/scene_gt.json)"},
      {{dir + "/stretched", "--split", "test"}, dir + "/stretched has no split folder test"},
  };
  for (const auto& [dataset, message] : cases) {
    std::vector<std::string> args = dataset;
    args.insert(args.end(), {"--out", dir + "/plots"});
    const Result result = RunStats(args, dir + "/bad");
    EXPECT_EQ(result.code, 2) << dataset[0];
    EXPECT_EQ(result.err, "stackgen-stats: error: " + message + "\n");
  }
  EXPECT_FALSE(fs::exists(dir + "/plots"));
}

}  // namespace
}  // namespace stackgen
