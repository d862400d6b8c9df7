#include "consumers/coco/coco_writer.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <limits>
#include <set>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "consumers/coco/coco_records.h"
#include "consumers/dataset/files.h"
#include "consumers/dataset/grasp_records.h"
#include "consumers/dataset/images.h"
#include "consumers/dataset/shards.h"
#include "contract/bounded_decode.h"
#include "contract/rle.h"
#include "contract/scene_contract.h"

namespace stackgen {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// id layout: image id = generator_id * 1e8 + seq + 1, annotation id = image id * 1000 +
// instance_id; kMaxGeneratorId and kMaxSeq of contract/scene_contract.h keep both unique and below
// 2^53, so a tool that reads JSON numbers as doubles (JavaScript, jq) tells every id apart
constexpr int64_t kSeqsPerGenerator = 100000000;
static_assert(kMaxSeq < kSeqsPerGenerator - 1, "a seq's image id would reach the next generator");
constexpr int32_t kMaxCocoInstanceId = 999;
static_assert((int64_t{kMaxGeneratorId} * kSeqsPerGenerator + kMaxSeq + 1) * 1000 +
                      kMaxCocoInstanceId <
                  (int64_t{1} << 53),
              "an annotation id would pass 2^53");

constexpr const char* kAnnotationsFile = "annotations.json";
constexpr const char* kJournalFile = "annotations.journal";
constexpr const char* kImagesFolder = "images";
constexpr const char* kShardsFolder = "shards";
constexpr std::string_view kTemporarySuffix = ".tmp";

// a journal line: {"image":IMAGE,"annotations":[ANNOTATIONS],"scene":SCENE}\n (see the header)
// version 2: image ids generator_id * 1e8 + seq + 1 (version 1: * 1e9)
constexpr int kJournalVersion = 2;
constexpr std::string_view kImagePrefix = "{\"image\":";
constexpr std::string_view kAnnotationsPrefix = ",\"annotations\":[";
constexpr std::string_view kScenePrefix = "],\"scene\":";

// images/<generator_id>_<seq:06>.png, .jpg for a JPEG scene
std::string ImageFileName(const stackgen::scene& scene) {
  char seq[32];
  std::snprintf(seq, sizeof(seq), "%06lld", static_cast<long long>(scene.header.seq));
  const bool jpeg = scene.color.encoding == stackgen::image::ENCODING_JPEG;
  return std::to_string(scene.header.generator_id) + "_" + seq + (jpeg ? ".jpg" : ".png");
}

// writes `records` (JSON values separated by ',' as in a journal line) to `out` separated by
// ",\n" instead, as annotations.json lists them
void WriteOnePerLine(std::string_view records, OutputFile& out) {
  int depth = 0;
  bool in_string = false, escaped = false;
  size_t start = 0;
  for (size_t i = 0; i < records.size(); ++i) {
    const char c = records[i];
    // inside a string only its end counts
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    // outside: nesting, and the commas between top-level values
    if (c == '"') {
      in_string = true;
    } else if (c == '{' || c == '[') {
      ++depth;
    } else if (c == '}' || c == ']') {
      --depth;
    } else if (c == ',' && depth == 0) {
      out.Write(records.substr(start, i + 1 - start));
      out.Write("\n");
      start = i + 1;
    }
  }
  out.Write(records.substr(start));
}

// whether `name` looks like an image file this writer writes: <digits>_<6+ digits>.png|.jpg
bool IsImageFileName(const std::string& name) {
  const size_t underscore = name.find('_');
  const size_t dot = name.rfind('.');
  if (underscore == std::string::npos || dot == std::string::npos || underscore == 0 ||
      dot < underscore + 7) {
    return false;
  }
  const auto digits = [&](size_t begin, size_t end) {
    return std::all_of(name.begin() + begin, name.begin() + end,
                       [](char c) { return c >= '0' && c <= '9'; });
  };
  const std::string extension = name.substr(dot);
  return digits(0, underscore) && digits(underscore + 1, dot) &&
         (extension == ".png" || extension == ".jpg");
}

}  // namespace

CocoWriter::CocoWriter(const std::string& dir, const CocoWriterOptions& options)
    : dir_(dir), options_(options) {
  if (options_.min_visib_fract &&
      !(*options_.min_visib_fract >= 0.0 && *options_.min_visib_fract <= 1.0)) {
    throw std::runtime_error("min_visib_fract " + std::to_string(*options_.min_visib_fract) +
                             " outside [0, 1]");
  }
  const fs::path folder(dir_);
  const std::string annotations = (folder / kAnnotationsFile).string();
  journal_path_ = (folder / kJournalFile).string();

  // never overwrite a dataset; resume one only from its journal
  const int64_t annotations_size = FileSize(annotations);
  const int64_t journal_size = FileSize(journal_path_);
  if (!options_.resume) {
    if (annotations_size > 0 && journal_size >= 0) {
      throw std::runtime_error(annotations +
                               " already exists; will not overwrite it (use --resume to extend "
                               "this dataset, or choose another output folder)");
    }
    if (annotations_size > 0) {
      throw std::runtime_error(annotations + " already exists and there is no " + kJournalFile +
                               " to resume it from; will not overwrite it (choose another output "
                               "folder or remove it)");
    }
    if (journal_size > 0) {
      throw DatasetStartedError(journal_path_);
    }
  } else if (annotations_size > 0 && journal_size < 0) {
    throw std::runtime_error("cannot resume " + annotations + " without its journal: " +
                             journal_path_ + " is missing (choose another output folder)");
  }

  if (options_.shard_images < 0 || options_.shard_images > kImagesPerChunk) {
    throw std::runtime_error("shard_images " + std::to_string(options_.shard_images) +
                             " outside 0..1000");
  }
  // the folders, each new one made durable in its parent
  std::vector<fs::path> created = CreateFolders(folder / kImagesFolder);
  if (options_.shard_images > 0) {
    for (const fs::path& path : CreateFolders(folder / kShardsFolder)) created.push_back(path);
  }
  // a writer that cannot open leaves nothing it made behind: the journal it created, empty, and
  // the folders it created, empty
  const bool journal_existed = FileSize(journal_path_) >= 0;
  const auto remove_created = [&] {
    if (!journal_existed && FileSize(journal_path_) == 0) unlink(journal_path_.c_str());
    std::error_code ignored;
    for (const fs::path& path : created) fs::remove(path, ignored);  // only if empty
  };
  try {
    // the journal, locked against a second writer; reloaded, or still empty now that it is ours
    journal_ = std::make_unique<Journal>(journal_path_);
    std::set<std::string> journaled_images;
    if (options_.resume) {
      journaled_images = LoadJournal();
    } else if (journal_->size() > 0) {
      throw DatasetStartedError(journal_path_);
    }
    // leftovers of an Add or a Finish that never completed
    CleanImagesFolder(journaled_images);
    if (options_.shard_images > 0) {
      // a shard or the index cut short by a crash; every shard is written again by Finish
      RemoveTemporaryFiles(folder / kShardsFolder);
      for (const auto& [image_id, entry] : index_) {
        dirty_shards_.insert(ShardId(entry.generator_id, entry.seq));
      }
    }
    const std::string annotations_temporary = annotations + std::string(kTemporarySuffix);
    if (unlink(annotations_temporary.c_str()) != 0 && errno != ENOENT) {
      throw SystemError("cannot remove", annotations_temporary, errno);
    }
    SyncFolder(folder);
  } catch (...) {
    journal_.reset();
    remove_created();
    throw;
  }
}

// the journal stays: it is the dataset's durable record
CocoWriter::~CocoWriter() = default;

std::set<std::string> CocoWriter::LoadJournal() {
  std::set<std::string> journaled_images;
  truncated_journal_bytes_ =
      journal_->Load([&](const std::string& line, uint64_t offset, int64_t line_number) {
        LoadJournalLine(line, offset, line_number, &journaled_images);
      });
  resumed_scenes_ = static_cast<int64_t>(index_.size());
  return journaled_images;
}

namespace {

// what is wrong with a journal line, thrown by the checks below (LoadJournalLine says where)
struct LineFault : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// where a journal line's image and annotation records lie, from the journal's start
struct RecordSpans {
  uint64_t image_offset = 0;
  uint64_t image_length = 0;
  uint64_t annotations_offset = 0;
  uint64_t annotations_length = 0;
};

// The spans of the line at `offset`: {"image":IMAGE,"annotations":[ANNOTATIONS],"scene":...,
// the lengths as `scene` gives them, checked against the line and its parsed `image`.
RecordSpans ReadSpans(const std::string& line, uint64_t offset, const json& image,
                      const json& scene) {
  const uint64_t image_length = scene.at("image_length").get<uint64_t>();
  const uint64_t annotations_length = scene.at("annotations_length").get<uint64_t>();
  const uint64_t annotations_start = kImagePrefix.size() + image_length + kAnnotationsPrefix.size();
  if (image_length > line.size() || annotations_length > line.size() ||
      annotations_start + annotations_length + kScenePrefix.size() > line.size() ||
      line.compare(0, kImagePrefix.size(), kImagePrefix) != 0 ||
      line.compare(kImagePrefix.size() + image_length, kAnnotationsPrefix.size(),
                   kAnnotationsPrefix) != 0 ||
      line.compare(annotations_start + annotations_length, kScenePrefix.size(), kScenePrefix) !=
          0 ||
      json::parse(line.substr(kImagePrefix.size(), image_length)) != image) {
    throw LineFault("image_length " + std::to_string(image_length) + " or annotations_length " +
                    std::to_string(annotations_length) + " does not match the line");
  }
  return {offset + kImagePrefix.size(), image_length, offset + annotations_start,
          annotations_length};
}

// A line's counts of annotations, crowd regions and dropped instances, checked against its
// annotation records.
void ReadCounts(const json& record, int64_t* annotations, int64_t* crowd, int64_t* dropped) {
  const json& scene = record["scene"];
  *annotations = scene.at("num_annotations").get<int64_t>();
  *crowd = scene.at("num_crowd").get<int64_t>();
  *dropped = scene.at("num_dropped").get<int64_t>();
  const json& records = record["annotations"];
  if (*annotations < 0 || *crowd < 0 || *dropped < 0 || !records.is_array() ||
      records.size() != static_cast<uint64_t>(*annotations + *crowd)) {
    throw LineFault("num_annotations " + std::to_string(*annotations) + " + num_crowd " +
                    std::to_string(*crowd) + " does not match the " +
                    std::to_string(records.size()) + " annotation records");
  }
}

// Throws unless the line was written with the same filter and mask form as `options` say.
void CheckSameOptions(const json& scene, const CocoWriterOptions& options) {
  const json& min_visib_fract = scene.at("min_visib_fract");
  const json own = options.min_visib_fract ? json(*options.min_visib_fract) : json(nullptr);
  if (min_visib_fract != own) {
    throw LineFault("written with min_visib_fract " + min_visib_fract.dump() +
                    ", this writer has " + own.dump() + " (resume with the same min_visib_fract)");
  }
  const bool polygons = scene.contains("polygons") && scene.at("polygons") == true;
  if (polygons != options.polygons) {
    throw LineFault(std::string("written ") + (polygons ? "with" : "without") +
                    " --polygons, this writer " + (options.polygons ? "with" : "without") +
                    " (resume with the same choice)");
  }
}

// A line's categories, which must agree with every earlier line's (`known`).
std::map<int32_t, std::string> ReadCategories(const json& scene,
                                              const std::map<int32_t, std::string>& known) {
  std::map<int32_t, std::string> categories;
  for (const json& category : scene.at("categories")) {
    const int32_t class_id = category.at(0).get<int32_t>();
    const std::string class_name = category.at(1).get<std::string>();
    const auto earlier = known.find(class_id);
    if (class_id < 1 || class_name.empty() ||
        (earlier != known.end() && earlier->second != class_name)) {
      throw LineFault("category " + category.dump() + " is not valid or differs from an earlier " +
                      "line's" +
                      (earlier != known.end() ? " \"" + earlier->second + "\"" : std::string()));
    }
    categories.emplace(class_id, class_name);
  }
  return categories;
}

}  // namespace

void CocoWriter::LoadJournalLine(const std::string& line, uint64_t offset, int64_t line_number,
                                 std::set<std::string>* journaled_images) {
  const std::string where = journal_path_ + " line " + std::to_string(line_number) + " (byte " +
                            std::to_string(offset) + ")";
  const auto corrupt = [&where](const std::string& text) {
    return std::runtime_error(where + ": " + text);
  };
  JournalEntry entry;
  SceneCounts counts;
  std::map<int32_t, std::string> scene_categories;
  std::string file_name;
  try {
    const json record = json::parse(line);
    if (!record.is_object() || !record.contains("image") || !record.contains("annotations") ||
        !record.contains("scene")) {
      throw corrupt("not a stackgen-coco journal line (image, annotations and scene expected)");
    }
    const json& scene = record["scene"];
    if (scene.at("journal_version") != kJournalVersion) {
      throw corrupt("journal_version " + scene["journal_version"].dump() + " is not " +
                    std::to_string(kJournalVersion) +
                    (scene["journal_version"] == 1
                         ? " (written by an older stackgen-coco, whose image ids were "
                           "generator_id * 10^9 + seq + 1: write to a new folder)"
                         : ""));
    }

    // the scene, once, and its image record
    const int64_t generator_id = scene.at("generator_id").get<int64_t>();
    const int64_t seq = scene.at("seq").get<int64_t>();
    const std::string scene_name =
        "scene " + std::to_string(generator_id) + "/" + std::to_string(seq);
    if (generator_id < 0 || generator_id > kMaxGeneratorId ||
        !SceneIdsInRange(static_cast<int32_t>(generator_id), seq)) {
      throw corrupt(scene_name + " is outside the id layout");
    }
    entry.generator_id = static_cast<int32_t>(generator_id);
    entry.seq = seq;
    entry.seed = record.at("image").at("stackgen").at("seed").get<int64_t>();
    if (scene.contains("run")) {
      if (!scene["run"].is_string()) throw corrupt("scene.run is not a string");
      runs_[entry.generator_id] = scene["run"].get<std::string>();
    }
    const int64_t image_id = ImageId(entry.generator_id, seq);
    if (index_.count(image_id) != 0) throw corrupt(scene_name + " is recorded twice");
    const json& image = record["image"];
    if (image.at("id") != image_id) {
      throw corrupt("image.id " + image["id"].dump() + " is not " + std::to_string(image_id) +
                    ", the id of " + scene_name);
    }
    file_name = image.at("file_name").get<std::string>();
    if (!IsImageFileName(file_name)) {
      throw corrupt("image.file_name \"" + file_name + "\" is not a name this writer gives");
    }

    const RecordSpans spans = ReadSpans(line, offset, image, scene);
    entry.image_offset = spans.image_offset;
    entry.image_length = spans.image_length;
    entry.annotations_offset = spans.annotations_offset;
    entry.annotations_length = spans.annotations_length;

    // its counts, written with this writer's options, and its categories
    ReadCounts(record, &counts.annotations, &counts.crowd, &counts.dropped);
    CheckSameOptions(scene, options_);
    scene_categories = ReadCategories(scene, categories_);
  } catch (const LineFault& fault) {
    throw corrupt(fault.what());
  } catch (const json::parse_error& error) {
    throw corrupt("not a journal record: invalid JSON at byte " + std::to_string(error.byte) +
                  " of the line (the journal is damaged; annotations.journal lines are written "
                  "only by stackgen-coco)");
  } catch (const json::exception& error) {
    throw corrupt(error.what());
  }

  // a valid line: index it
  Index(entry, counts);
  categories_.insert(scene_categories.begin(), scene_categories.end());
  journaled_images->insert(file_name);
}

void CocoWriter::CleanImagesFolder(const std::set<std::string>& journaled_images) const {
  const fs::path images = fs::path(dir_) / kImagesFolder;
  const size_t present =
      CleanUnrecorded(images, images, journaled_images, options_.resume, IsImageFileName);
  CheckRecordedFiles(images, journaled_images, present, journal_path_);
}

void CocoWriter::Index(const JournalEntry& entry, const SceneCounts& counts) {
  index_.emplace(ImageId(entry.generator_id, entry.seq), entry);
  num_annotations_ += counts.annotations;
  num_crowd_ += counts.crowd;
  num_dropped_ += counts.dropped;
  // StoredThrough moves on while the next seq is there
  int64_t& through = stored_through_.emplace(entry.generator_id, -1).first->second;
  while (Has(entry.generator_id, through + 1)) ++through;
}

int64_t CocoWriter::ImageId(int32_t generator_id, int64_t seq) {
  return int64_t{generator_id} * kSeqsPerGenerator + seq + 1;
}

int64_t CocoWriter::AnnotationId(int64_t image_id, int32_t instance_id) {
  return image_id * 1000 + instance_id;
}

void CocoWriter::Validate(const stackgen::scene& scene) const {
  // the contract every consumer checks (contract/scene_contract.h)
  std::string why;
  if (!CheckScene(scene, &why)) FailScene(scene, why);

  // a PNG or JPEG file is stored as it came: it must decode, whole
  if (scene.color.encoding != stackgen::image::ENCODING_RAW &&
      DecodeImage(scene.color, &why).empty()) {
    FailScene(scene, "color." + why);
  }

  // what COCO and this dataset need beyond it: annotation ids (image id * 1000 + instance_id),
  // JSON text, one name per class_id across the dataset
  std::map<int32_t, std::string> scene_categories;
  for (size_t i = 0; i < scene.instances.size(); ++i) {
    const stackgen::instance& instance = scene.instances[i];
    const std::string field = "instances[" + std::to_string(i) + "]";
    if (instance.instance_id > kMaxCocoInstanceId) {
      FailScene(scene, field + ".instance_id " + std::to_string(instance.instance_id) +
                           " outside 1.." + std::to_string(kMaxCocoInstanceId) +
                           " (annotation id = image id * 1000 + instance_id)");
    }
    if (!IsUtf8(instance.class_name)) FailScene(scene, field + ".class_name is not valid UTF-8");
    // the name stored (or staged) before for this class
    const std::string* known = nullptr;
    for (const auto* seen : {&categories_, &staged_categories_}) {
      const auto found = seen->find(instance.class_id);
      if (known == nullptr && found != seen->end()) known = &found->second;
    }
    const auto in_scene = scene_categories.emplace(instance.class_id, instance.class_name).first;
    if ((known != nullptr && *known != instance.class_name) ||
        in_scene->second != instance.class_name) {
      FailScene(scene, field + ".class_name \"" + instance.class_name + "\" differs from \"" +
                           (known != nullptr ? *known : in_scene->second) +
                           "\" seen before for class_id " + std::to_string(instance.class_id));
    }
  }
}

void CocoWriter::WriteImageFile(const stackgen::scene& scene, const std::string& path,
                                bool sync) const {
  const stackgen::image& color = scene.color;
  if (color.encoding != stackgen::image::ENCODING_RAW) {
    // PNG and JPEG: the bytes as they came
    WriteFileAtomically(path, reinterpret_cast<const char*>(color.data.data()), color.data.size(),
                        sync);
    return;
  }
  // RAW: encode to PNG
  std::string why;
  const std::vector<uint8_t> png = EncodeImage(DecodeImage(color, &why), -1);
  WriteFileAtomically(path, reinterpret_cast<const char*>(png.data()), png.size(), sync);
}

std::string CocoWriter::AnnotationRecords(const stackgen::scene& scene, int64_t image_id,
                                          SceneCounts* counts) const {
  std::vector<const stackgen::instance*> instances;
  for (const stackgen::instance& instance : scene.instances) instances.push_back(&instance);
  std::sort(instances.begin(), instances.end(),
            [](const stackgen::instance* a, const stackgen::instance* b) {
              return a->instance_id < b->instance_id;
            });
  const stackgen::camera_info& camera = scene.camera;
  std::string annotations;
  for (const stackgen::instance* instance : instances) {
    // the generator's label decides: annotated -> iscrowd 0, ignored -> iscrowd 1, else nothing;
    // a min_visib_fract of our own only drops more
    const bool below_own_threshold =
        options_.min_visib_fract && instance->visib_fract < *options_.min_visib_fract;
    const bool crowd = instance->ignored;
    const bool annotation_kept = instance->annotated && !below_own_threshold;
    if (!annotation_kept && !crowd) {
      ++counts->dropped;
      continue;
    }
    json segmentation = {{"size", {camera.height, camera.width}},
                         {"counts", instance->mask_visib_rle}};
    if (options_.polygons && !crowd) {
      cv::Mat mask(camera.height, camera.width, CV_8UC1, cv::Scalar(0));
      DecodeRleInto(instance->mask_visib_rle, camera.height, camera.width, mask.data);
      segmentation = MaskPolygons(mask);
    }
    json annotation =
        AnnotationRecord(*instance, AnnotationId(image_id, instance->instance_id), image_id, camera,
                         std::move(segmentation), crowd);
    // stackgen's own labels beyond COCO's: the instance's grasps, when it has some
    json grasps = GraspsJson(scene, instance->instance_id);
    if (!grasps.empty()) annotation["stackgen"] = std::move(grasps);
    if (!annotations.empty()) annotations += ",";
    annotations += annotation.dump();
    if (crowd) {
      ++counts->crowd;
    } else {
      ++counts->annotations;
    }
  }
  return annotations;
}

bool CocoWriter::Add(const stackgen::scene& scene) {
  // store each (generator_id, seq) once; the same ids with another seed come from another run
  CheckSceneIds(scene);
  const int64_t image_id = ImageId(scene.header.generator_id, scene.header.seq);
  if (IsRepeat(scene, SeenSeed(index_, staged_seeds_, image_id))) return false;
  Validate(scene);

  // the image record
  const std::string file_name = ImageFileName(scene);
  const json image = ImageRecord(scene, image_id, file_name);

  // the annotation records, by instance id (= by annotation id)
  SceneCounts counts;
  const std::string annotations = AnnotationRecords(scene, image_id, &counts);

  // the journal line: the records, then the scene's counts and categories
  const std::string image_text = image.dump();
  std::map<int32_t, std::string> scene_categories;
  for (const stackgen::instance& instance : scene.instances) {
    scene_categories.emplace(instance.class_id, instance.class_name);
  }
  json categories = json::array();
  for (const auto& [class_id, class_name] : scene_categories) {
    categories.push_back({class_id, class_name});
  }
  json scene_record = {{"journal_version", kJournalVersion},
                       {"generator_id", scene.header.generator_id},
                       {"seq", scene.header.seq},
                       {"num_annotations", counts.annotations},
                       {"num_crowd", counts.crowd},
                       {"num_dropped", counts.dropped},
                       {"categories", std::move(categories)},
                       {"min_visib_fract",
                        options_.min_visib_fract ? json(*options_.min_visib_fract) : json(nullptr)},
                       {"image_length", image_text.size()},
                       {"annotations_length", annotations.size()}};
  if (options_.polygons) scene_record["polygons"] = true;
  const auto run = runs_.find(scene.header.generator_id);
  if (run != runs_.end()) scene_record["run"] = run->second;
  std::string line;
  line.append(kImagePrefix).append(image_text).append(kAnnotationsPrefix).append(annotations);
  line.append(kScenePrefix).append(scene_record.dump()).append("}\n");

  // the image, then (at the commit) the line that records it; a failed line takes the image
  // with it
  const std::string image_path = (fs::path(dir_) / kImagesFolder / file_name).string();
  WriteImageFile(scene, image_path, !options_.group_commit);
  StagedScene staged_scene;
  JournalEntry& entry = staged_scene.entry;
  entry.generator_id = scene.header.generator_id;
  entry.seq = scene.header.seq;
  entry.seed = scene.header.seed;
  entry.image_offset = kImagePrefix.size();
  entry.image_length = image_text.size();
  entry.annotations_offset = entry.image_offset + image_text.size() + kAnnotationsPrefix.size();
  entry.annotations_length = annotations.size();
  staged_scene.counts = counts;
  staged_scene.line = std::move(line);
  staged_scene.image_path = image_path;
  staged_.push_back(std::move(staged_scene));
  staged_seeds_.emplace(image_id, scene.header.seed);
  for (const auto& category : scene_categories) {
    if (categories_.count(category.first) == 0) staged_categories_.insert(category);
  }
  if (!options_.group_commit) Commit();
  return true;
}

std::vector<std::pair<int32_t, int64_t>> CocoWriter::Commit() {
  std::vector<std::pair<int32_t, int64_t>> committed;
  if (staged_.empty()) return committed;
  // group commits sync the image files in one go (without, each Add synced its image and the
  // folder); on failure nothing staged stays: its image files go
  std::vector<std::string> lines, files;
  for (const StagedScene& staged : staged_) {
    lines.push_back(staged.line);
    files.push_back(staged.image_path);
  }
  uint64_t line_offset = 0;
  try {
    line_offset = CommitGroup(journal_.get(), lines, files, options_.group_commit,
                              (fs::path(dir_) / kImagesFolder).string());
  } catch (...) {
    staged_.clear();
    staged_seeds_.clear();
    staged_categories_.clear();
    throw;
  }
  // index them where their lines now lie
  for (const StagedScene& staged : staged_) {
    JournalEntry entry = staged.entry;
    entry.image_offset += line_offset;
    entry.annotations_offset += line_offset;
    Index(entry, staged.counts);
    committed.emplace_back(entry.generator_id, entry.seq);
    line_offset += staged.line.size();
  }
  categories_.insert(staged_categories_.begin(), staged_categories_.end());
  staged_.clear();
  staged_seeds_.clear();
  staged_categories_.clear();
  // a full shard is written now, the others by Finish
  if (options_.shard_images > 0) {
    for (const auto& [generator_id, seq] : committed)
      dirty_shards_.insert(ShardId(generator_id, seq));
    for (const auto& [generator_id, seq] : committed) {
      const int64_t shard = ShardId(generator_id, seq);
      if (dirty_shards_.count(shard) == 0) continue;
      // its seqs: [first, last) within the chunk of seq
      const int64_t chunk_first = seq / kImagesPerChunk * kImagesPerChunk;
      const int64_t first =
          chunk_first + (seq - chunk_first) / options_.shard_images * options_.shard_images;
      const int64_t last = std::min(first + options_.shard_images, chunk_first + kImagesPerChunk);
      const auto begin = index_.lower_bound(ImageId(generator_id, first));
      const auto end = index_.lower_bound(ImageId(generator_id, last));
      if (std::distance(begin, end) == last - first) {
        WriteShard(shard);
        dirty_shards_.erase(shard);
      }
    }
  }
  return committed;
}

int64_t CocoWriter::ShardId(int32_t generator_id, int64_t seq) const {
  const int64_t chunk = int64_t{generator_id} * 1000000 + seq / kImagesPerChunk;
  return ShardOf(chunk, seq % kImagesPerChunk, options_.shard_images);
}

void CocoWriter::WriteShard(int64_t shard_id) {
  // the generator and seqs it holds (see ShardId)
  const int64_t per_chunk = (kImagesPerChunk + options_.shard_images - 1) / options_.shard_images;
  const int64_t chunk = shard_id / per_chunk;
  const int32_t generator_id = static_cast<int32_t>(chunk / 1000000);
  const int64_t first =
      chunk % 1000000 * kImagesPerChunk + shard_id % per_chunk * options_.shard_images;
  const int64_t last =
      std::min(first + options_.shard_images, chunk % 1000000 * kImagesPerChunk + kImagesPerChunk);
  // each image and its records under one key, in seq order
  std::vector<std::pair<std::string, std::string>> members;
  for (auto it = index_.lower_bound(ImageId(generator_id, first));
       it != index_.end() && it->first < ImageId(generator_id, last); ++it) {
    const JournalEntry& entry = it->second;
    const std::string image = journal_->Read(entry.image_offset, entry.image_length);
    const std::string file_name = json::parse(image).at("file_name").get<std::string>();
    const std::string key = file_name.substr(0, file_name.rfind('.'));
    members.emplace_back(file_name,
                         ReadWholeFile((fs::path(dir_) / kImagesFolder / file_name).string()));
    members.emplace_back(
        key + ".json", "{\"annotations\":[" +
                           (entry.annotations_length > 0
                                ? journal_->Read(entry.annotations_offset, entry.annotations_length)
                                : std::string()) +
                           "],\"image\":" + image + "}");
  }
  WriteTar(fs::path(dir_) / kShardsFolder / ShardFileName(shard_id), members);
}

void CocoWriter::Finish() {
  Commit();
  // the shards behind the journal, and the index of every key
  if (options_.shard_images > 0) {
    for (const int64_t shard : dirty_shards_) WriteShard(shard);
    dirty_shards_.clear();
    std::map<std::string, int64_t> keys;
    char key[64];
    for (const auto& [image_id, entry] : index_) {
      std::snprintf(key, sizeof(key), "%d_%06lld", entry.generator_id,
                    static_cast<long long>(entry.seq));
      keys.emplace(key, ShardId(entry.generator_id, entry.seq));
    }
    WriteKeyToShard(fs::path(dir_) / kShardsFolder / "key_to_shard.json", keys);
  }
  const fs::path final_path = fs::path(dir_) / kAnnotationsFile;
  const std::string temporary = final_path.string() + std::string(kTemporarySuffix);
  try {
    OutputFile out(temporary);

    // info and licenses: no date, so the same scenes give the same bytes
    const json info = {{"description", options_.description},
                       {"version", "1.0"},
                       {"contributor", "stackgen-coco"},
                       {"url", ""}};
    out.Write("{\n\"info\": " + info.dump() + ",\n\"licenses\": [],\n\"images\": [\n");

    // images, by id, as the journal holds them
    bool first = true;
    for (const auto& [image_id, entry] : index_) {
      if (!first) out.Write(",\n");
      first = false;
      out.Write(journal_->Read(entry.image_offset, entry.image_length));
    }

    // categories, by id
    out.Write("\n],\n\"categories\": [\n");
    first = true;
    for (const auto& [class_id, class_name] : categories_) {
      if (!first) out.Write(",\n");
      first = false;
      out.Write(json{{"id", class_id}, {"name", class_name}, {"supercategory", "part"}}.dump());
    }

    // annotations, by id (image ids ascending, instance ids ascending within an image), one per
    // line
    out.Write("\n],\n\"annotations\": [\n");
    first = true;
    for (const auto& [image_id, entry] : index_) {
      if (entry.annotations_length == 0) continue;
      if (!first) out.Write(",\n");
      first = false;
      WriteOnePerLine(journal_->Read(entry.annotations_offset, entry.annotations_length), out);
    }
    out.Write("\n]\n}\n");
    out.Close();
  } catch (...) {
    unlink(temporary.c_str());
    throw;
  }

  // publish it whole, durably
  if (rename(temporary.c_str(), final_path.c_str()) != 0) {
    const int error = errno;
    unlink(temporary.c_str());
    throw std::runtime_error("cannot rename " + temporary + " to " + final_path.string() + ": " +
                             std::strerror(error));
  }
  SyncFolder(final_path.parent_path());
}

std::map<int32_t, int64_t> CocoWriter::LostPerGenerator() const {
  return LostBetween(StoredSeqs());
}

int64_t CocoWriter::StoredThrough(int32_t generator_id) const {
  const auto found = stored_through_.find(generator_id);
  return found == stored_through_.end() ? -1 : found->second;
}

bool CocoWriter::Has(int32_t generator_id, int64_t seq) const {
  if (!SceneIdsInRange(generator_id, seq)) return false;
  return index_.count(ImageId(generator_id, seq)) != 0;
}

void CocoWriter::SetRun(int32_t generator_id, const std::string& run) { runs_[generator_id] = run; }

std::map<int32_t, std::vector<int64_t>> CocoWriter::StoredSeqs() const {
  // the index is sorted by generator, then seq
  std::map<int32_t, std::vector<int64_t>> seqs;
  for (const auto& [image_id, entry] : index_) seqs[entry.generator_id].push_back(entry.seq);
  return seqs;
}

}  // namespace stackgen
