// stackgen-coco: writes the scenes published on STACKGEN_SCENE into a COCO instances dataset.

#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "bus/channels.h"
#include "cli/flags.h"
#include "consumers/coco/coco_writer.h"
#include "consumers/dataset/writer_main.h"

namespace {

constexpr const char* kProgram = "stackgen-coco";

struct Flags {
  stackgen::WriterFlags writer;
  std::optional<double> min_visib_fract;  // unset: follow the generator's labels
  int64_t shards = 0;
  bool polygons = false;
};

void PrintHelp() {
  std::printf(
      "Usage: %s --out DIR [--count N] [--resume] [--lcm-url URL]\n"
      "       [--bus-key-file FILE | --open-bus] [--replay]\n"
      "       [--min-visib-fract F] [--polygons] [--shards N] [--window N] [--group-commit N]\n"
      "       [--fault-drop F]\n"
      "\n"
      "Writes every scene published on %s into a COCO instances dataset:\n"
      "DIR/annotations.json and DIR/images/<generator_id>_<seq:06>.png (.jpg for JPEG scenes).\n"
      "DIR/annotations.journal is the durable record of every scene stored (annotations.json\n"
      "is made from it). Stops after N scenes, or on SIGINT/SIGTERM, and always leaves a valid\n"
      "dataset of the scenes stored.\n"
      "\n"
      "Delivery: it is a reliable consumer. It sends credits on STACKGEN_CREDIT (per generator:\n"
      "stored through which seq, how many more it can take), so no generator runs more than\n"
      "--window scenes ahead of what it stored; it asks for missed seqs on STACKGEN_RESEND; it\n"
      "stores every scene of every generator (from seq 0) exactly once, keeping generators apart\n"
      "by generator_id; it publishes its counters on STACKGEN_STATUS every second. A scene\n"
      "that fails the checks (its PNG or JPEG is decoded whole first) is refused, counted and\n"
      "asked for again; a seq is given up after 3 bad copies. On a file://\n"
      "LCM log (file://LOG?speed=0) it only reads.\n"
      "\n"
      "The generator's labels decide what is written: an instance it marks annotated becomes an\n"
      "annotation (iscrowd 0), one it marks ignored (its occlusion rule IGNORE) an ignore region\n"
      "(iscrowd 1), any other is dropped. Every annotation holds the visible mask (segmentation,\n"
      "area, bbox) and the full one (amodal_segmentation, px_count_all, amodal_bbox).\n"
      "\n"
      "Options:\n"
      "  --out DIR             dataset folder (required): new or empty; with --resume, one\n"
      "                        that holds its annotations.journal. Anything else is refused:\n"
      "                        nothing is ever written over.\n"
      "%s"
      "  --min-visib-fract F   also drop annotated objects whose visible fraction (visib_fract)\n"
      "                        is below F, 0..1: a stricter filter than the generator's\n"
      "                        annotation.min_visib_fract; it never adds objects the generator\n"
      "                        did not annotate and leaves ignore regions alone (default: none,\n"
      "                        follow the generator).\n"
      "  --polygons            iscrowd-0 segmentations as polygons (one per piece of the\n"
      "                        visible mask, through its boundary pixels' centres; holes\n"
      "                        filled) for loaders that want them (torchvision's references,\n"
      "                        DETR); ignore regions stay RLE (default: RLE for all).\n"
      "  --shards N            also write webdataset tar shards of at most N images, 1..1000:\n"
      "                        DIR/shards/shard-ID.tar, each image's KEY.png and KEY.json\n"
      "                        ({\"annotations\": [...], \"image\": {...}}, the records of\n"
      "                        annotations.json) under KEY = <generator_id>_<seq:06>, and\n"
      "                        key_to_shard.json, to stream a large set into a DataLoader\n"
      "                        (default 0: none).\n"
      "  --help                print this help and exit.\n"
      "\n"
      "Exit status: 0 done, 1 error, 2 bad command line.\n",
      kProgram, stackgen::kSceneChannel, stackgen::WriterFlagsHelp("annotations.journal").c_str());
}

// a fraction as %g prints it
std::string FormatFraction(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  stackgen::FlagParser parser(kProgram);
  stackgen::AddWriterFlags(&parser, &flags.writer);
  parser.Double("--min-visib-fract", &flags.min_visib_fract, stackgen::Interval::Closed(0, 1));
  parser.Int("--shards", &flags.shards, 0, 1000);
  parser.Switch("--polygons", &flags.polygons);
  parser.ParseOrExit(argc, argv, PrintHelp);

  stackgen::WriterProgram program;
  program.name = kProgram;
  program.journal = "annotations.journal";
  program.open = [&](const stackgen::WriterFlags& writer_flags) {
    stackgen::CocoWriterOptions options;
    options.min_visib_fract = flags.min_visib_fract;
    options.resume = writer_flags.resume;
    options.group_commit = writer_flags.group_commit > 1;
    options.shard_images = static_cast<int>(flags.shards);
    options.polygons = flags.polygons;
    return std::make_unique<stackgen::CocoWriter>(writer_flags.out, options);
  };
  program.summary = [&](const stackgen::DatasetSink& sink) {
    const auto& writer = static_cast<const stackgen::CocoWriter&>(sink);
    const std::string dropped_reason =
        flags.min_visib_fract
            ? "not annotated, or visib_fract < " + FormatFraction(*flags.min_visib_fract)
            : std::string("not annotated");
    return std::string(kProgram) + ": wrote " + flags.writer.out +
           "/annotations.json: " + std::to_string(writer.num_images()) + " images, " +
           std::to_string(writer.num_annotations()) + " annotations, " +
           std::to_string(writer.num_crowd()) + " ignore regions (iscrowd 1), " +
           std::to_string(writer.num_dropped()) + " dropped (" + dropped_reason + "), " +
           std::to_string(writer.num_lost()) + " lost; " +
           stackgen::ClassesText(writer.categories());
  };
  return stackgen::RunWriter(program, flags.writer);
}
