#pragma once

// The postures of the instances in a dataset: a COCO file written by stackgen-coco, a BOP
// dataset folder written by stackgen-bop, or an LCM log (lcm-logger) of STACKGEN_LABELS or
// STACKGEN_SCENE messages.

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace stackgen::stats {

/// The orientation of one instance, in the bin (world) frame.
struct PostureSample {
  std::string class_name;
  /// Posture angles of world_R_reference = Rz(alpha) Ry(beta) Rx(gamma), degrees: alpha and
  /// gamma in (-180, 180], beta in [-90, 90] (gen/annotate/pose.h PostureAnglesDeg).
  double alpha_deg = 0.0;
  double beta_deg = 0.0;
  double gamma_deg = 0.0;
  /// The angle about the vertical: world_R_reference = Rz(heading) S where S turns about a
  /// horizontal axis (the twist of the rotation about world Z), degrees in (-180, 180]; NaN when
  /// S is a half turn and the heading is undefined.
  double heading_deg = 0.0;
  /// Index of the convex-hull face that points down (0 = largest); -1 when unknown (always in
  /// BOP datasets).
  int resting_face = -1;
  /// The scene (pile) it lies in: 0.. in the order scenes were first read. Instances of one
  /// pile are not independent; the pile tests permute whole scenes.
  int64_t scene = 0;
  /// The pile it lies in: scenes that share a part position (to 1e-6 mm: the views of one
  /// settled pile, physics.views_per_pile) are one pile, numbered 0.. by their first scene;
  /// otherwise a pile is a scene. The pile tests permute whole piles.
  int64_t pile = 0;
  /// Where its origin is in the bin (world) frame, mm (origin at the centre of the inner floor,
  /// z up); NaN when the dataset does not say (a COCO file without world_t_m2w). In a BOP
  /// dataset cam_R_w2c^T (cam_t_m2c - cam_t_w2c).
  Eigen::Vector3d world_position_mm = Eigen::Vector3d::Constant(std::nan(""));
};

/// What was read from one file.
struct Dataset {
  std::string path;
  /// "COCO", "BOP" or "LCM log".
  std::string kind;
  /// BOP: the split folder read (its name, "train_pbr"); empty for the other kinds.
  std::string split;
  /// Images (COCO, BOP: in scene id, image id order) or distinct scenes (log: by generator_id
  /// and seq) read, with or without instances used; PostureSample::scene counts them.
  int64_t scenes = 0;
  /// Piles among the scenes with instances used (see PostureSample::pile).
  int64_t piles = 0;
  /// Log messages that repeated a scene already read (the same scene on STACKGEN_LABELS and
  /// STACKGEN_SCENE, or a resend).
  int64_t repeated_scenes = 0;
  /// Logs: bytes of an incomplete last event that were ignored (a logger stopped mid-write).
  int64_t truncated_bytes = 0;
  /// Instances left out because they are not annotated, without all_instances: logs' instances
  /// with annotated false, COCO ignore regions (iscrowd 1), BOP ground truths with visib_fract
  /// below kBopMinVisibFract (consumers/bop/bop_dataset.h).
  int64_t not_annotated = 0;
  /// Instances left out because they are of another class than the one asked for.
  int64_t other_class = 0;
  /// The instances used, in file order.
  std::vector<PostureSample> samples;
  /// Instances used per class name.
  std::map<std::string, int64_t> class_counts;
};

/// How to read a dataset.
struct ReadOptions {
  /// Per class name, the rotation object_R_reference of the reference frame the posture is
  /// measured in; classes not listed use the object (mesh) frame.
  std::map<std::string, Eigen::Matrix3d> object_R_reference;
  /// Only instances of this class; empty: all.
  std::string class_name;
  /// Also instances that are not annotated (too hidden): in logs and BOP datasets every
  /// instance, in COCO files the ignore regions (iscrowd 1) as well; a COCO file holds no other
  /// instances.
  bool all_instances = false;
  /// The split folder of BOP datasets; empty: train_pbr, else the only split there (see
  /// FindBopSplit in consumers/bop/bop_dataset.h). Not used for the other kinds.
  std::string bop_split;
  /// The bus key that LCM logs are checked with (bus/auth.h): "" for ResolveBusKeyFile's choice,
  /// or none at all with `open_bus` (a log recorded on an open bus).
  std::string bus_key_file;
  bool open_bus = false;
};

/// The posture of an instance whose rotation is world_R_object, measured in the reference frame
/// object_R_reference of its class.
PostureSample PostureOf(const Eigen::Matrix3d& world_R_object,
                        const Eigen::Matrix3d& object_R_reference);

/// The angle about world Z of `world_R_reference` (see PostureSample::heading_deg), degrees.
double HeadingDeg(const Eigen::Matrix3d& world_R_reference);

/// Reads the dataset at `path`, telling a COCO file (JSON starting with '{') from an LCM log
/// (event magic 0xEDA1DA01) by its content. A folder is a COCO dataset when it holds
/// annotations.json, else a BOP dataset when it holds a split folder (options.bop_split). The
/// rotation of an instance is world_R_m2w (COCO), world_from_object.rotation (log) or
/// cam_R_w2c^T cam_R_m2c of its image (BOP); a COCO annotation without world_R_m2w falls back to
/// its posture_deg. BOP class names come from the categories of scene_gt_coco.json, else are
/// "obj_OBJ_ID" (six digits, as the model files). Throws std::runtime_error with one line naming
/// the file and, where there is one, the record and field at fault, for a file that cannot be
/// read, is no kind, or holds a bad record (a missing field, a matrix that is not a rotation, a
/// BOP image without its camera).
Dataset ReadDataset(const std::string& path, const ReadOptions& options);

}  // namespace stackgen::stats
