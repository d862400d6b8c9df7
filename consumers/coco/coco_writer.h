#pragma once

#include <cstdint>
#include <fstream>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>

#include <stackgen/scene.hpp>

namespace stackgen {

/// Thrown by CocoWriter::Add for a scene whose contents disagree with each other; the text names
/// the scene (generator_id/seq) and the field at fault. Nothing of such a scene is written.
class InvalidSceneError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// How a CocoWriter builds its dataset.
struct CocoWriterOptions {
  /// Unset (the default): follow the generator's labels. An instance marked `annotated` becomes
  /// an annotation (iscrowd 0), one marked `ignored` an ignore region (iscrowd 1), any other is
  /// not written (counted as dropped). Set (0..1): annotated instances whose visib_fract is
  /// below it are dropped as well, a stricter filter than the generator's; it never brings back
  /// an instance the generator did not annotate, and does not touch ignore regions.
  std::optional<double> min_visib_fract;
  /// The dataset's info.description.
  std::string description = "stackgen: synthetic images of parts piled in a bin";
};

/// Streams stackgen::scene messages into a COCO instances dataset in a folder:
/// `annotations.json` and `images/<generator_id>_<seq:06>.png` (`.jpg` for JPEG scenes).
/// Each Add writes the image file and appends the scene's image and annotation records as JSON
/// fragments to an on-disk journal (`annotations.journal`); only a small index stays in memory.
/// Finish streams the journal, sorted by id, into annotations.json. Ids: image id =
/// generator_id * 1000000000 + seq + 1, annotation id = image id * 1000 + instance_id, so a
/// dataset does not depend on the order scenes arrive in. Categories come from the scenes'
/// class_id and class_name. Not thread-safe.
class CocoWriter {
 public:
  /// Opens a dataset in `dir`, creating it and `dir/images` if missing. Throws
  /// std::runtime_error if `dir` already holds a non-empty annotations.json (it is never
  /// overwritten), if min_visib_fract is set and outside [0, 1], or if a folder or the journal
  /// cannot be created.
  explicit CocoWriter(const std::string& dir, const CocoWriterOptions& options = {});
  /// Removes the journal if the dataset was finished after the last Add or holds no scene;
  /// otherwise leaves it (annotations.json is never written here).
  ~CocoWriter();
  CocoWriter(const CocoWriter&) = delete;
  CocoWriter& operator=(const CocoWriter&) = delete;

  /// Validates `scene` and stores it: writes its colour image to images/ (PNG and JPEG bytes as
  /// they are, RAW encoded to PNG; through a temporary file and a rename; the image record's
  /// file_name is relative to images/, as COCO loaders expect) and journals its records.
  /// Every annotation (iscrowd 0 or 1) has the COCO fields (segmentation = the visible mask,
  /// area = px_count_visib, bbox = bbox_visib, iscrowd), the amodal ones (amodal_segmentation =
  /// mask_obj_rle, amodal_bbox = bbox_obj, px_count_all) and stackgen's (instance_id,
  /// visib_fract, px_count_visib, bbox_obj, posture_deg, resting_face, cam_R_m2c, cam_t_m2c,
  /// world_R_m2w, world_t_m2w).
  /// Returns false, writing nothing, if a scene with the same (generator_id, seq) was stored
  /// already. Throws InvalidSceneError naming the field if the scene is inconsistent (image size
  /// vs camera, data size, encoding, num_instances, an instance_id outside 1..999 or repeated, a
  /// class name that differs from an earlier scene's, mask_visib_rle or mask_obj_rle that is
  /// empty or does not decode to width * height pixels of which px_count_visib resp.
  /// px_count_all are set, an instance both annotated and ignored, or either with no visible
  /// pixel, a value that is not finite, generator_id or seq out of range), and
  /// std::runtime_error naming the file if writing fails.
  bool Add(const stackgen::scene& scene);

  /// Writes `annotations.json` with every scene stored so far: streams the journal into
  /// `annotations.json.tmp`, then renames it, so annotations.json is never half-written. Images
  /// and annotations are sorted by id, categories by id. May be called again after more Adds.
  /// Throws std::runtime_error naming the file if reading or writing fails.
  void Finish();

  /// The dataset folder.
  const std::string& dir() const { return dir_; }
  /// Scenes (= images) stored.
  int64_t num_images() const { return static_cast<int64_t>(index_.size()); }
  /// Annotations written with iscrowd 0 (annotated instances, less those below min_visib_fract
  /// when it is set).
  int64_t num_annotations() const { return num_annotations_; }
  /// Ignore regions written: annotations with iscrowd 1 (instances the generator marked
  /// ignored).
  int64_t num_crowd() const { return num_crowd_; }
  /// Instances not written at all: neither annotated nor ignored, or annotated but below
  /// min_visib_fract when it is set.
  int64_t num_dropped() const { return num_dropped_; }
  /// Per generator_id, the seqs missing between the first and the last seq stored.
  std::map<int32_t, int64_t> LostPerGenerator() const;
  /// The sum of LostPerGenerator.
  int64_t num_lost() const;

  /// The image id of a scene: generator_id * 1000000000 + seq + 1.
  static int64_t ImageId(int32_t generator_id, int64_t seq);
  /// The annotation id of an instance: image_id * 1000 + instance_id.
  static int64_t AnnotationId(int64_t image_id, int32_t instance_id);

 private:
  // where a scene's fragments lie in the journal
  struct JournalEntry {
    int32_t generator_id = 0;
    int64_t seq = 0;
    uint64_t image_offset = 0;
    uint64_t image_length = 0;
    uint64_t annotations_offset = 0;
    uint64_t annotations_length = 0;  // 0: the scene has no annotations
  };

  void Validate(const stackgen::scene& scene) const;
  std::string WriteImageFile(const stackgen::scene& scene) const;
  uint64_t AppendToJournal(const std::string& text);

  std::string dir_;
  CocoWriterOptions options_;
  std::string journal_path_;
  std::ofstream journal_;
  uint64_t journal_size_ = 0;
  std::map<int64_t, JournalEntry> index_;      // by image id
  std::map<int32_t, std::string> categories_;  // class_id -> class_name
  int64_t num_annotations_ = 0;
  int64_t num_crowd_ = 0;
  int64_t num_dropped_ = 0;
  bool finished_ = false;
};

}  // namespace stackgen
