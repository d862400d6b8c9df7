// stackgen-bop: writes the scenes published on STACKGEN_SCENE, and the models on STACKGEN_MODEL,
// into a BOP dataset.

#include <cstdio>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <stackgen/model.hpp>

#include "bus/channels.h"
#include "cli/flags.h"
#include "consumers/bop/bop_writer.h"
#include "consumers/dataset/writer_main.h"

namespace {

constexpr const char* kProgram = "stackgen-bop";

struct Flags {
  stackgen::WriterFlags writer;
  std::string split = "train_pbr";
  int64_t jpeg_quality = 0;
  int64_t shards = 0;
  bool point_clouds = false;
};

void PrintHelp() {
  std::printf(
      "Usage: %s --out DIR [--count N] [--resume] [--lcm-url URL]\n"
      "       [--bus-key-file FILE | --open-bus] [--replay]\n"
      "       [--split NAME] [--jpeg-quality Q] [--shards N] [--point-clouds] [--window N]\n"
      "       [--group-commit N] [--fault-drop F]\n"
      "\n"
      "Writes every scene published on %s into a dataset in the BOP format\n"
      "(thodan/bop_toolkit docs/bop_datasets_format.md), for training and evaluating 6D pose\n"
      "estimators:\n"
      "  DIR/camera.json, DIR/models/obj_OBJ_ID.ply and models_info.json (from %s),\n"
      "  DIR/SPLIT/SCENE_ID/{rgb,depth,mask,mask_visib}/ and scene_camera.json,\n"
      "  scene_gt.json, scene_gt_info.json, scene_gt_coco.json. Scenes with a 3D camera's depth\n"
      "  (config sensor_3d) store it in depth/ and the exact depth in depth_ideal/.\n"
      "A model not heard by the time --count scenes are stored is waited for up to 6 s\n"
      "(generators send their models every 5 s and at their end), then said on stderr.\n"
      "OBJ_ID is the class id; a SCENE_ID folder (a chunk) holds 1000 consecutive scenes of one\n"
      "generator: SCENE_ID = generator_id * 1000000 + seq / 1000, image id = seq %% 1000.\n"
      "Every labelled instance is a ground truth (distractors are not objects of the dataset);\n"
      "poses in millimetres, rotations row-major, depth uint16 x depth_scale, masks 0/255.\n"
      "DIR/bop.journal is the durable record of every scene stored (the chunks' JSON files are\n"
      "made from it once a chunk is full, and at the end). Stops after N scenes, or on\n"
      "SIGINT/SIGTERM, and always leaves a valid dataset of the scenes stored.\n"
      "\n"
      "Delivery: a reliable consumer, like stackgen-coco: credits, resends, every scene of every\n"
      "generator stored exactly once, counters on STACKGEN_STATUS; a scene that fails the checks\n"
      "(colour and depth decoded whole first) is refused, counted and asked for again.\n"
      "\n"
      "Options:\n"
      "  --out DIR             dataset folder (required): new or empty; with --resume, one\n"
      "                        that holds its bop.journal. Anything else is refused: nothing\n"
      "                        is ever written over.\n"
      "%s"
      "  --split NAME          the split folder (default train_pbr; BOP: train, val, test).\n"
      "  --jpeg-quality Q      store colour images as JPEG of quality Q, 1..100, as BOP's PBR\n"
      "                        sets are (default 0: PNG as the generator sent them; JPEG scenes\n"
      "                        are kept as they came either way).\n"
      "  --shards N            also write webdataset tar shards of at most N images, 1..1000\n"
      "                        (BOP-webdataset: DIR/shards/shard-ID.tar, each image's rgb, depth,\n"
      "                        camera, gt, gt_info, mask and mask_visib under one key SCENE_IM,\n"
      "                        and key_to_shard.json), to stream a large set into a DataLoader\n"
      "                        (default 0: none). Shard ID = SCENE_ID * ceil(1000 / N) + image\n"
      "                        id / N.\n"
      "  --point-clouds        also write each image's depth (the 3D camera's where there is\n"
      "                        one) as an organised point cloud, SCENE_ID/points/IM_ID.ply:\n"
      "                        binary PLY, width x height points in the camera frame, mm, NaN\n"
      "                        where there is no depth (default: none).\n"
      "  --help                print this help and exit.\n"
      "\n"
      "Exit status: 0 done, 1 error, 2 bad command line.\n",
      kProgram, stackgen::kSceneChannel, stackgen::kModelChannel,
      stackgen::WriterFlagsHelp("bop.journal").c_str());
}

// the classes of the scenes stored whose model has not been heard, ascending
std::vector<int32_t> MissingModels(const stackgen::BopWriter& writer) {
  const std::set<int32_t> models = writer.ModelClasses();
  std::vector<int32_t> missing;
  for (const auto& [class_id, class_name] : writer.classes()) {
    if (models.count(class_id) == 0) missing.push_back(class_id);
  }
  return missing;
}

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  stackgen::AddWriterFlags(&parser, &flags.writer);
  parser.String("--split", &flags.split, "a folder name");
  parser.Int("--jpeg-quality", &flags.jpeg_quality, 0, 100);
  parser.Int("--shards", &flags.shards, 0, 1000);
  parser.Switch("--point-clouds", &flags.point_clouds);
  parser.ParseOrExit(argc, argv, PrintHelp);

  stackgen::WriterProgram program;
  program.name = kProgram;
  program.journal = "bop.journal";
  program.open = [&](const stackgen::WriterFlags& writer_flags) {
    stackgen::BopWriterOptions options;
    options.split = flags.split;
    options.jpeg_quality = static_cast<int>(flags.jpeg_quality);
    options.shard_images = static_cast<int>(flags.shards);
    options.point_clouds = flags.point_clouds;
    options.resume = writer_flags.resume;
    options.group_commit = writer_flags.group_commit > 1;
    return std::make_unique<stackgen::BopWriter>(writer_flags.out, options);
  };
  // the models: stored when first heard; a bad one is reported once per class
  std::set<int32_t> reported;
  program.subscribe = [&](stackgen::Bus& bus, stackgen::DatasetSink& sink) {
    auto& writer = static_cast<stackgen::BopWriter&>(sink);
    bus.Subscribe<stackgen::model>(
        stackgen::kModelChannel,
        [&writer, &reported](const stackgen::model& model) {
          try {
            if (writer.AddModel(model)) {
              std::printf("%s: stored the model of class %d (%s): %d vertices, %d triangles\n",
                          kProgram, model.class_id, model.class_name.c_str(), model.num_vertices,
                          model.num_triangles);
              std::fflush(stdout);
            } else if (writer.conflicting_models().count(model.class_id) != 0 &&
                       reported.insert(model.class_id).second) {
              std::fprintf(stderr,
                           "%s: warning: generator %d sends another mesh for class %d than the "
                           "one stored; kept the stored one\n",
                           kProgram, model.header.generator_id, model.class_id);
            }
          } catch (const stackgen::InvalidSceneError& error) {
            if (reported.insert(model.class_id).second) {
              std::fprintf(stderr, "%s: refused a model: %s\n", kProgram, error.what());
            }
          }
        },
        16,
        [](const std::string& text) {
          std::fprintf(stderr, "%s: skipped a model message: %s\n", kProgram, text.c_str());
        });
  };
  // the models a generator has not been heard to send yet: the writer listens on for them once
  // --count scenes are stored
  program.missing = [](const stackgen::DatasetSink& sink) {
    const std::vector<int32_t> classes =
        MissingModels(static_cast<const stackgen::BopWriter&>(sink));
    std::string text;
    for (const int32_t class_id : classes) {
      text += (text.empty() ? "" : ", ") + std::to_string(class_id);
    }
    if (classes.empty()) return text;
    return (classes.size() == 1 ? "the model of class " : "the models of classes ") + text;
  };
  program.summary = [&](const stackgen::DatasetSink& sink) {
    const auto& writer = static_cast<const stackgen::BopWriter&>(sink);
    std::string missing;
    for (const int32_t class_id : MissingModels(writer)) {
      missing += (missing.empty() ? " (no model heard for obj " : ", ") + std::to_string(class_id);
    }
    if (!missing.empty()) missing += ")";
    const std::set<int32_t> models = writer.ModelClasses();
    return std::string(kProgram) + ": wrote " + flags.writer.out + ": " +
           std::to_string(writer.num_images()) + " images in " +
           std::to_string(writer.num_chunks()) + " chunks of " + flags.split + ", " +
           std::to_string(writer.num_ground_truths()) + " ground truths" +
           (flags.shards > 0 ? ", shards of " + std::to_string(flags.shards) + " images" : "") +
           ", models of " + std::to_string(models.size()) + " classes" + missing + ", " +
           std::to_string(writer.num_lost()) + " lost; " + stackgen::ClassesText(writer.classes());
  };
  return stackgen::RunWriter(program, flags.writer);
}
