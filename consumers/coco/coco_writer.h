#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <stackgen/scene.hpp>

#include "consumers/dataset/dataset_sink.h"
#include "consumers/dataset/journal.h"

namespace stackgen {

/// How a CocoWriter builds its dataset.
struct CocoWriterOptions {
  /// Unset (the default): follow the generator's labels. An instance marked `annotated` becomes
  /// an annotation (iscrowd 0), one marked `ignored` an ignore region (iscrowd 1), any other is
  /// not written (counted as dropped). Set (0..1): annotated instances whose visib_fract is
  /// below it are dropped as well, a stricter filter than the generator's; it never brings back
  /// an instance the generator did not annotate, and does not touch ignore regions.
  std::optional<double> min_visib_fract;
  /// False (the default): every segmentation is compressed RLE. True: an annotation's (iscrowd
  /// 0) is a list of polygons instead, one per piece of its visible mask, through the centres of
  /// the piece's boundary pixels (x + 0.5, y + 0.5 in COCO's pixel coordinates; straight runs as
  /// their two ends); holes are filled, as COCO polygons cannot hold them, and a piece of one
  /// or two pixels becomes the square around them. Ignore regions (iscrowd 1) stay RLE, as COCO
  /// keeps crowd regions. Recorded in the journal: a dataset is resumed with the same choice.
  bool polygons = false;
  /// The dataset's info.description.
  std::string description = "stackgen: synthetic images of parts piled in a bin";
  /// False (the default): start a new dataset; a folder that already holds one (a non-empty
  /// annotations.json or annotations.journal) is refused. True: continue the dataset in the
  /// folder from its journal (after a crash, a kill or a clean Finish alike): every scene
  /// recorded there counts as stored, a record torn by a crash is cut off, and later Adds and
  /// Finish extend the same dataset. A missing or empty folder starts a new dataset either way.
  bool resume = false;
  /// False (the default): every Add is durable when it returns (the image file and the folder
  /// are synced before its journal line is written and synced: three syncs per scene). True:
  /// group commits. Add only stages a scene (its image file written and renamed into place, its
  /// journal line held in memory) and Commit makes every staged scene durable at once: one
  /// syncfs of the file system that holds the dataset (the images and their names; it also
  /// writes out other programs' pending data on that file system), then the journal lines in
  /// one write and one sync. A staged scene counts as stored only once committed (num_images,
  /// Has, StoredThrough); a crash loses the staged ones, and a resumed writer removes their
  /// image files.
  bool group_commit = false;
  /// 0 (the default): no shards. 1..1000: also webdataset tar shards of at most this many images
  /// in DIR/shards/ (consumers/dataset/shards.h): each image's KEY = <generator_id>_<seq:06>
  /// holds KEY.png (or .jpg) and KEY.json, {"annotations":[...],"image":{...}} with the records
  /// annotations.json has for it; key_to_shard.json maps every key to its shard. Shard =
  /// (generator_id * 1000000 + seq / 1000) * ceil(1000 / N) + seq % 1000 / N, whatever order
  /// scenes arrive in. A shard is written whole once it is full, the others and the index by
  /// Finish (after a resume: all of them). The images/ folder and annotations.json stay.
  int shard_images = 0;
};

/// Streams stackgen::scene messages into a COCO instances dataset in a folder:
/// `annotations.json` and `images/<generator_id>_<seq:06>.png` (`.jpg` for JPEG scenes).
/// The writer's durable record is the journal `annotations.journal`: each Add writes the image
/// file, then appends one line to the journal holding the scene's image record, its annotation
/// records and its counts, and syncs both to disk before it returns (with group commits, Commit
/// does that for every scene added since the last one); only a small index stays in
/// memory. annotations.json is derived from the journal: Finish streams the journal, sorted by
/// id, into it. The journal is kept after Finish, so a dataset (finished or cut short by a crash)
/// can be resumed and extended (CocoWriterOptions::resume). Ids: image id =
/// generator_id * 100000000 + seq + 1, annotation id = image id * 1000 + instance_id, so a
/// dataset does not depend on the order scenes arrive in. Categories come from the scenes'
/// class_id and class_name. One writer per folder at a time (the journal is locked); not
/// thread-safe.
///
/// Journal format: UTF-8, one line per scene, each a JSON object laid out as
///   {"image":IMAGE,"annotations":[A1,A2,...],"scene":SCENE}\n
/// IMAGE is the scene's record of annotations.json "images" and A1, A2, ... its records of
/// "annotations", byte for byte as Finish writes them (which puts a line break after each comma
/// between records); SCENE is
///   {"annotations_length":n,"categories":[[class_id,"class_name"],...],"generator_id":g,
///    "image_length":n,"journal_version":1,"min_visib_fract":x or null,"num_annotations":n,
///    "num_crowd":n,"num_dropped":n,"run":"seed S, config PATH (sha256 HEX)","seq":s}
/// ("run" only once the generator's run is known: see SetRun)
/// where image_length and annotations_length are the byte lengths of IMAGE and of the text
/// between the brackets of "annotations". A line is complete once its '\n' is written; a last
/// line without one is a torn write, cut off on resume.
class CocoWriter : public DatasetSink {
 public:
  /// Opens a dataset in `dir`, creating it and `dir/images` if missing, and removes leftover
  /// temporary files (images/*.tmp, annotations.json.tmp). With options.resume, reloads the
  /// journal: its scenes count as stored, a torn last line is cut off (see
  /// truncated_journal_bytes), and image files that no journal line names (written by an Add
  /// that never completed) are removed. Throws std::runtime_error naming the file if: without
  /// resume, `dir` holds a non-empty annotations.json or annotations.journal; with resume, it
  /// holds annotations.json but no journal, a journal line that is complete but not a valid
  /// record (the message gives its line number and byte offset), a line whose image file is
  /// missing, or lines written with another min_visib_fract; min_visib_fract is set and outside
  /// [0, 1]; another writer has the journal open; a folder or the journal cannot be created,
  /// read, written or synced.
  explicit CocoWriter(const std::string& dir, const CocoWriterOptions& options = {});
  /// Closes the journal; the journal stays (annotations.json is never written here).
  ~CocoWriter() override;
  CocoWriter(const CocoWriter&) = delete;
  CocoWriter& operator=(const CocoWriter&) = delete;

  /// Validates `scene` and stores it: writes its colour image to images/ (PNG and JPEG bytes as
  /// they are, RAW encoded to PNG; through a temporary file, synced to disk before it is renamed
  /// into place; the image record's file_name is relative to images/, as COCO loaders expect),
  /// then appends its journal line and syncs it. When Add returns true the scene is on disk for
  /// good: it survives a crash or a power cut and is kept by a resumed writer (with
  /// options.group_commit: once Commit has returned it).
  /// Every annotation (iscrowd 0 or 1) has the COCO fields (segmentation = the visible mask,
  /// area = px_count_visib, bbox = bbox_visib, iscrowd), the amodal ones (amodal_segmentation =
  /// mask_obj_rle, amodal_bbox = bbox_obj, px_count_all) and stackgen's (instance_id,
  /// visib_fract, px_count_visib, bbox_obj, posture_deg, resting_face, cam_R_m2c, cam_t_m2c,
  /// world_R_m2w, world_t_m2w).
  /// Returns false, writing nothing, if a scene with the same (generator_id, seq) and seed was
  /// stored already; one with another seed (another run with the same generator id) throws
  /// InvalidSceneError. Throws InvalidSceneError naming the field if the scene is inconsistent
  /// (image size vs camera, data size, encoding, num_instances, an instance_id outside 1..999 or
  /// repeated, a class name that is not UTF-8 or differs from an earlier scene's, mask_visib_rle or
  /// mask_obj_rle that is empty or does not decode to width * height pixels of which
  /// px_count_visib resp. px_count_all are set, an instance both annotated and ignored, or
  /// either with no visible pixel, a value that is not finite, generator_id or seq out of
  /// range), and std::runtime_error naming the file and the system's reason ("cannot write
  /// DIR/images/0_000012.png.tmp: No space left on device") if writing fails. After either
  /// throw nothing of the scene is on disk or in the writer (its temporary file is removed, the
  /// journal cut back to its previous length), and the writer can go on: later Adds and Finish
  /// work when there is room again. (Should cutting the journal back fail as well, later Adds
  /// throw until the dataset is resumed, which cuts a torn line off.)
  /// With options.group_commit, the scene is only staged when Add returns true (see
  /// CocoWriterOptions::group_commit) and a staged scene counts as seen for the same-id rules.
  bool Add(const stackgen::scene& scene) override;

  /// Makes every staged scene durable (see CocoWriterOptions::group_commit) and returns their
  /// (generator_id, seq), in the order they were added; nothing when none is staged. Throws
  /// std::runtime_error naming the file and the system's reason if a sync or the journal write
  /// fails; then none of the staged scenes is kept (their image files are removed, the journal
  /// is cut back) and the writer can go on.
  std::vector<std::pair<int32_t, int64_t>> Commit() override;
  /// Scenes added but not yet committed.
  int64_t num_staged() const override { return static_cast<int64_t>(staged_.size()); }

  /// Commits what is staged, then writes `annotations.json` with every scene stored so far:
  /// streams the journal into
  /// `annotations.json.tmp`, syncs it, then renames it, so annotations.json is never
  /// half-written. Images and annotations are sorted by id, categories by id. May be called
  /// again after more Adds. Throws std::runtime_error naming the file and the system's reason
  /// if reading or writing fails; then any previous annotations.json is left as it was and the
  /// temporary file is removed.
  void Finish() override;
  std::string finished_files() const override { return "annotations.json"; }

  /// The dataset folder.
  const std::string& dir() const { return dir_; }
  /// Scenes (= images) stored, those reloaded from the journal included.
  int64_t num_images() const override { return static_cast<int64_t>(index_.size()); }
  /// Annotations written with iscrowd 0 (annotated instances, less those below min_visib_fract
  /// when it is set).
  int64_t num_annotations() const { return num_annotations_; }
  /// Ignore regions written: annotations with iscrowd 1 (instances the generator marked
  /// ignored).
  int64_t num_crowd() const { return num_crowd_; }
  /// Instances not written at all: neither annotated nor ignored, or annotated but below
  /// min_visib_fract when it is set.
  int64_t num_dropped() const { return num_dropped_; }
  /// class_id -> class_name of the scenes stored (the COCO categories).
  const std::map<int32_t, std::string>& categories() const { return categories_; }
  /// Per generator_id, the seqs missing between the first and the last seq stored.
  std::map<int32_t, int64_t> LostPerGenerator() const override;

  /// The highest seq s of generator `generator_id` such that every seq 0..s is stored; -1 if
  /// seq 0 is not (or the generator is unknown).
  int64_t StoredThrough(int32_t generator_id) const;
  /// Whether the scene (generator_id, seq) is stored; false for ids outside the id layout.
  bool Has(int32_t generator_id, int64_t seq) const;
  /// Every stored seq, ascending, per generator_id.
  std::map<int32_t, std::vector<int64_t>> StoredSeqs() const override;

  /// The run (a RunName, session/delivery.h) each generator's scenes come from: read from the
  /// journal on resume (its last scene that names one), or set by SetRun.
  const std::map<int32_t, std::string>& Runs() const override { return runs_; }
  /// Scenes of `generator_id` added from now on are journalled as coming from `run` (the journal
  /// line's SCENE gets "run":run), so that a resumed dataset knows which run to continue.
  void SetRun(int32_t generator_id, const std::string& run) override;

  /// Scenes reloaded from the journal when the writer was opened with resume (0 without).
  int64_t resumed_scenes() const { return resumed_scenes_; }
  /// Bytes of a torn last journal line cut off when the writer was opened with resume (0 if the
  /// journal ended with a complete line).
  int64_t truncated_journal_bytes() const override { return truncated_journal_bytes_; }

  /// The image id of a scene: generator_id * 100000000 + seq + 1.
  static int64_t ImageId(int32_t generator_id, int64_t seq);
  /// The annotation id of an instance: image_id * 1000 + instance_id.
  static int64_t AnnotationId(int64_t image_id, int32_t instance_id);

 private:
  // where a scene's records lie in the journal (byte offsets from its start)
  struct JournalEntry {
    int32_t generator_id = 0;
    int64_t seq = 0;
    int64_t seed = 0;  // header.seed: a repeat with another seed is another run's scene
    uint64_t image_offset = 0;
    uint64_t image_length = 0;
    uint64_t annotations_offset = 0;
    uint64_t annotations_length = 0;  // 0: the scene has no annotations
  };
  // a scene's counts, as its journal line holds them
  struct SceneCounts {
    int64_t annotations = 0;
    int64_t crowd = 0;
    int64_t dropped = 0;
  };

  // a scene added but not committed: its journal line, where its records lie in the line, its
  // counts and its image file
  struct StagedScene {
    JournalEntry entry;  // offsets from the start of `line`
    SceneCounts counts;
    std::string line;
    std::string image_path;
  };

  void Validate(const stackgen::scene& scene) const;
  // the scene's annotation records as a journal line holds them (comma-separated, by instance
  // id), and their counts: annotated instances, crowd regions, and dropped ones
  std::string AnnotationRecords(const stackgen::scene& scene, int64_t image_id,
                                SceneCounts* counts) const;
  // writes the scene's colour image to `path` (see Add); `sync`: synced before it is renamed
  // into place, and the folder after
  void WriteImageFile(const stackgen::scene& scene, const std::string& path, bool sync) const;
  // indexes every complete journal line and cuts a torn last one off; returns the image file
  // names the lines record
  std::set<std::string> LoadJournal();
  void LoadJournalLine(const std::string& line, uint64_t offset, int64_t line_number,
                       std::set<std::string>* journaled_images);
  // removes temporary files from images/ (and with resume image files no line records); throws
  // if a journaled image is missing
  void CleanImagesFolder(const std::set<std::string>& journaled_images) const;
  // adds a stored scene to the index, the counts and StoredThrough
  void Index(const JournalEntry& entry, const SceneCounts& counts);
  // the shard of a scene, and the writing of one (shard_images)
  int64_t ShardId(int32_t generator_id, int64_t seq) const;
  void WriteShard(int64_t shard_id);

  std::string dir_;
  CocoWriterOptions options_;
  std::string journal_path_;
  std::unique_ptr<Journal> journal_;
  std::map<int64_t, JournalEntry> index_;             // by image id
  std::map<int32_t, std::string> categories_;         // class_id -> class_name
  std::map<int32_t, int64_t> stored_through_;         // generator_id -> StoredThrough
  std::vector<StagedScene> staged_;                   // added, not committed, in order
  std::map<int64_t, int64_t> staged_seeds_;           // their image ids -> header.seed
  std::map<int32_t, std::string> staged_categories_;  // classes first seen in staged scenes
  std::map<int32_t, std::string> runs_;               // generator_id -> RunName of its scenes
  std::set<int64_t> dirty_shards_;                    // shards whose file is behind the journal
  int64_t num_annotations_ = 0;
  int64_t num_crowd_ = 0;
  int64_t num_dropped_ = 0;
  int64_t resumed_scenes_ = 0;
  int64_t truncated_journal_bytes_ = 0;
};

}  // namespace stackgen
