#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <stackgen/model.hpp>
#include <stackgen/scene.hpp>

#include "consumers/dataset/dataset_sink.h"
#include "consumers/dataset/journal.h"

namespace stackgen {

/// How a BopWriter builds its dataset.
struct BopWriterOptions {
  /// The split folder the images go to (BOP: train_pbr for synthetic training images).
  std::string split = "train_pbr";
  /// 0 (the default): colour images stored as they came (PNG; a RAW scene encoded to PNG, a JPEG
  /// one kept). 1..100: stored as JPEG of this quality, as BOP's PBR training sets are.
  int jpeg_quality = 0;
  /// As CocoWriterOptions::resume: continue the dataset in the folder from its journal.
  bool resume = false;
  /// 0 (the default): no shards. 1..1000: also webdataset shards of at most this many images
  /// (see the class comment).
  int shard_images = 0;
  /// As CocoWriterOptions::group_commit: Add only stages a scene (its files written and renamed
  /// into place, its journal line held) and Commit makes the staged scenes durable at once (one
  /// syncfs, one journal write and sync). Without, every Add is durable when it returns.
  bool group_commit = false;
  /// Also each image's depth as an organised point cloud, SCENE_ID/points/IM_ID.ply (see the
  /// class comment). Default false.
  bool point_clouds = false;
};

/// Streams stackgen::scene messages into a dataset in the BOP-scenewise format
/// (thodan/bop_toolkit docs/bop_datasets_format.md), in a folder DIR:
///
///   DIR/camera.json                      cx, cy, depth_scale, fx, fy, height, width (the first
///                                        scene's camera; per-image cameras are in scene_camera)
///   DIR/models/obj_OBJ_ID.ply            the mesh of each class, ASCII PLY with normals, mm
///   DIR/models/models_info.json          diameter, min_x/y/z, size_x/y/z, symmetries
///   DIR/SPLIT/SCENE_ID/rgb/IM_ID.png     colour (.jpg with jpeg_quality; gray/ for GRAY8 scenes)
///   DIR/SPLIT/SCENE_ID/depth/IM_ID.png   uint16 depth; depth_mm = value * depth_scale: as the
///                                        3D camera measures it when the scenes carry its depth
///                                        (config sensor_3d; 0 = no depth), else the exact depth
///   DIR/SPLIT/SCENE_ID/depth_ideal/IM_ID.png   the exact depth, beside the 3D camera's only
///   DIR/SPLIT/SCENE_ID/points/IM_ID.ply  with point_clouds: depth/'s points in the camera frame,
///                                        mm, an organised cloud (PointCloudPly, model_files.h)
///   DIR/SPLIT/SCENE_ID/mask/IM_ID_GT_ID.png, mask_visib/IM_ID_GT_ID.png   0/255 masks
///   DIR/SPLIT/SCENE_ID/scene_camera.json, scene_gt.json, scene_gt_info.json, scene_gt_coco.json
///   DIR/SPLIT/SCENE_ID/scene_grasp.json  when the scenes carry grasps (config grasps): per
///                                        image, one object per ground truth in scene_gt's
///                                        order, {"suction_grasps": [...],
///                                        "parallel_jaw_grasps": [...]}, a key where it has
///                                        grasps of that kind (grasp_records.h)
///
/// Ids (all six digits in file names): obj_id = class_id; a chunk (BOP "scene") holds 1000
/// consecutive seqs of one generator: SCENE_ID = generator_id * 1000000 + seq / 1000, IM_ID =
/// seq % 1000, so a dataset does not depend on the order scenes arrive in. GT_ID numbers the
/// instances of an image by instance_id (distractors are not instances, so not objects of the
/// dataset). Every instance is a ground truth, however hidden (visib_fract tells). The files
/// hold what the toolkit's scripts compute, exactly where our labels allow: scene_gt_info boxes
/// as misc.calc_2d_bbox gives them (width and height max - min, one less than COCO's, and
/// [-1, -1, -1, -1] for no pixels, bbox_obj too when nothing is visible); in scene_gt_coco.json
/// the ground truths with visible pixels, "ignore" when visib_fract < 0.1 (calc_gt_coco.py),
/// bbox the amodal box (its default), the segmentation the visible mask as COCO compressed RLE
/// (the toolkit writes uncompressed runs; pycocotools reads both). Where our labels differ:
/// px_count_all and bbox_obj cover the silhouette inside the image (the toolkit's also count the
/// part of a truncated object outside it), and visibility is exact from the instance map (the
/// toolkit's depth test with delta 5 mm also counts as visible what lies less than 5 mm behind
/// another surface). Poses and models stay in the frame of the part's mesh file (BOP's datasets put
/// the origin at the centre of the model's box; ours is the CAD file's).
///
/// With shard_images N, the images also go into webdataset tar shards as BOP-webdataset has
/// them (bop_toolkit bop_toolkit_lib/dataset/bop_webdataset.py), for streaming a large set into a
/// DataLoader from object storage:
///
///   DIR/shards/shard-SHARD_ID.tar        at most N images, by key; each image KEY =
///                                        SCENE_ID_IM_ID has KEY.rgb.png (or .jpg; gray.png),
///                                        KEY.depth.png (KEY.depth_ideal.png beside a 3D
///                                        camera's), KEY.camera.json, KEY.gt.json,
///                                        KEY.gt_info.json, KEY.mask.json, KEY.mask_visib.json
///                                        (gt id -> uncompressed COCO RLE, as the toolkit's)
///   DIR/shards/key_to_shard.json         every key -> its SHARD_ID
///
/// SHARD_ID = SCENE_ID * ceil(1000 / N) + IM_ID / N: a shard holds consecutive images of one
/// chunk, and which shard an image goes to does not depend on the order scenes arrive in. A
/// shard is written (whole, through a temporary file) with its chunk's JSON files; the index by
/// Finish. The scenewise files stay.
///
/// The durable record is DIR/bop.journal: each Add writes the scene's image files, then one
/// journal line holding its records, synced before it returns (with group commits, at Commit).
/// The chunk JSON files are made from the journal: when a chunk has all its 1000 images, and by
/// Finish for every chunk changed since the last Finish (on resume: every chunk), each through a
/// temporary file renamed into place. JSON is written byte for byte as the toolkit's
/// inout.save_json writes it: sorted keys, one entry per line, Python's float repr. Models are
/// written when AddModel first hears a class. One writer per folder at a time (the journal is
/// locked); not thread-safe.
///
/// Journal format: UTF-8, one JSON object per line:
///   {"camera":SCENE_CAMERA,"coco":[ANNOTATION,...],"gt":[SCENE_GT,...],"gt_info":[INFO,...],
///    "scene":{"classes":[[class_id,"class_name"],...],"files":[...],"generator_id":g,
///             "height":h,"im_id":i,"journal_version":1,"rgb":"rgb/000000.png","run":"...",
///             "scene_id":s,"seed":x,"seq":q,"width":w},
///    "masks":[["full RLE","visible RLE"],...]}
/// ("run" only once the generator's run is known; "files": the scene's image files relative to
/// DIR)
/// where SCENE_CAMERA, SCENE_GT and INFO are the image's records of the chunk files and
/// ANNOTATION its scene_gt_coco annotations without "id" (numbered when the chunk is written).
class BopWriter : public DatasetSink {
 public:
  /// Opens (or with options.resume reloads) the dataset in `dir` as CocoWriter does: refuses a
  /// folder that holds a journal without resume, reloads the journal with resume (a torn last
  /// line cut off, files of scenes never committed removed, a line whose files are missing
  /// refused), removes temporary files, reads models_info.json and camera.json when present.
  /// Throws std::runtime_error naming the file and the reason.
  explicit BopWriter(const std::string& dir, const BopWriterOptions& options = {});
  ~BopWriter() override;
  BopWriter(const BopWriter&) = delete;
  BopWriter& operator=(const BopWriter&) = delete;

  /// Checks `scene` (contract/scene_contract.h CheckScene, its colour and depth decoded whole, a
  /// depth image present, class names one per class_id, at most 999999 instances) and stores it
  /// (see the class comment). Returns false, writing nothing, for a scene stored or staged
  /// already with the same seed; throws InvalidSceneError naming the field for a bad scene or a
  /// repeat with another seed, std::runtime_error naming the file for a write error; after a
  /// throw nothing of the scene is on disk or in the writer.
  bool Add(const scene& scene) override;
  std::vector<std::pair<int32_t, int64_t>> Commit() override;
  int64_t num_staged() const override { return static_cast<int64_t>(staged_.size()); }
  /// Commits, then writes the JSON files of every chunk changed since the last Finish.
  void Finish() override;
  std::string finished_files() const override { return "the chunks' JSON files"; }

  /// Stores the model of a class when it is the first heard for it: models/obj_ID.ply and
  /// models_info.json (rewritten whole), durably. Returns true when it wrote them, false when
  /// the class has a model already (a different mesh for it is not stored: see
  /// conflicting_models). Throws InvalidSceneError for a model that does not agree with itself
  /// (counts, indices, values that are not finite, class_id outside 1..999999) and
  /// std::runtime_error naming the file for a write error.
  bool AddModel(const model& message);
  /// Classes for which a model with another mesh was heard after the stored one.
  const std::set<int32_t>& conflicting_models() const { return conflicting_models_; }
  /// Classes with a model stored.
  std::set<int32_t> ModelClasses() const;
  /// Classes that instances of the stored scenes belong to.
  const std::map<int32_t, std::string>& classes() const { return classes_; }

  int64_t num_images() const override { return static_cast<int64_t>(index_.size()); }
  /// Ground truths (instances) stored.
  int64_t num_ground_truths() const { return num_ground_truths_; }
  /// Chunks (BOP scenes) holding at least one image.
  int64_t num_chunks() const;
  std::map<int32_t, int64_t> LostPerGenerator() const override;
  std::map<int32_t, std::vector<int64_t>> StoredSeqs() const override;
  const std::map<int32_t, std::string>& Runs() const override { return runs_; }
  void SetRun(int32_t generator_id, const std::string& run) override;
  int64_t truncated_journal_bytes() const override { return truncated_journal_bytes_; }
  /// The folder of chunk `scene_id` relative to the dataset: "train_pbr/000000".
  std::string ChunkFolder(int64_t scene_id) const;

  /// BOP's scene id and image id of a scene (see the class comment).
  static int64_t SceneId(int32_t generator_id, int64_t seq);
  static int64_t ImageId(int64_t seq);

 private:
  // a stored scene: where its journal line lies
  struct Entry {
    int32_t generator_id = 0;
    int64_t seq = 0;
    int64_t seed = 0;
    uint64_t offset = 0;
    uint64_t length = 0;  // without the '\n'
  };
  // a scene added but not committed
  struct Staged {
    Entry entry;  // offset from the start of `line`
    std::string line;
    std::vector<std::string> files;  // absolute paths, to remove if it is dropped
    std::map<int32_t, std::string> classes;
    int64_t ground_truths = 0;
  };

  void Validate(const scene& scene) const;
  void LoadJournalLine(const std::string& line, uint64_t offset, int64_t line_number,
                       std::set<std::string>* files);
  // removes temporary files, and with resume image files no journal line names; throws if a
  // journaled file is missing
  void CleanFolders(const std::set<std::string>& journaled_files) const;
  void Index(const Entry& entry);
  void WriteChunk(int64_t scene_id);
  void WriteKeyToShard() const;
  int64_t ShardId(int64_t scene_id, int64_t im_id) const;
  void WriteModelsInfo() const;

  std::string dir_;
  BopWriterOptions options_;
  std::unique_ptr<Journal> journal_;
  std::map<std::pair<int64_t, int64_t>, Entry> index_;  // by (scene_id, im_id)
  std::map<std::pair<int64_t, int64_t>, int64_t> staged_seeds_;
  std::vector<Staged> staged_;
  std::map<int32_t, std::string> classes_;  // class_id -> class_name, of stored scenes
  std::map<int32_t, std::string> runs_;
  std::set<int64_t> dirty_chunks_;
  std::map<int32_t, std::string> models_info_;  // obj_id -> its models_info.json entry (JSON)
  std::map<int32_t, std::string> model_files_;  // obj_id -> its PLY text, as heard this run
  std::set<int32_t> conflicting_models_;
  bool camera_written_ = false;
  int64_t num_ground_truths_ = 0;
  int64_t truncated_journal_bytes_ = 0;
};

}  // namespace stackgen
