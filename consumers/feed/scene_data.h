#pragma once

// What a learner needs from a scene message, in C++ so that the Python feed is fast: the checks
// that every field agrees with the others before a scene is handed out, image decoding into
// arrays, and COCO RLE decoding into masks. Consumers do not link gen/, hence the small RLE
// decoder here (the writer's one only counts runs).

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <stackgen/scene.hpp>

#include "contract/rle.h"

namespace stackgen {
class Bus;
}  // namespace stackgen

namespace stackgen::feed {

/// A scene or a stream that cannot be used; the text names the scene, field, file or URL.
class FeedError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The bus at `url` (resolved as every program resolves --lcm-url) with BusOptions' key_file and
/// open_bus, for the feed's helpers that only publish or listen. Throws FeedError with the
/// reason (a bad URL, an unreadable key) if it cannot be opened.
std::unique_ptr<Bus> OpenBus(const std::string& url, const std::string& key_file, bool open_bus);

/// The image of `field` ("color", "depth", "instance_map", "depth_sensor") decoded: RGB8 as
/// CV_8UC3 in R, G, B order, GRAY8 as CV_8UC1, DEPTH16 and INSTANCE16 as CV_16UC1. A RAW image is
/// not copied: the matrix points into `message.data`, which must outlive it. Throws FeedError
/// naming the field if the data does not decode to the size and format the message declares.
cv::Mat DecodeImage(const image& message, const std::string& field);

/// Checks that a decoded scene message is one a learner can use: the contract every consumer
/// checks (stackgen::CheckScene, contract/scene_contract.h) and an instance map. Returns false with
/// a one-line reason naming the field in `*why`.
bool CheckFeedScene(const scene& message, std::string* why);

/// One scene handed to a learner: the message, and its images decoded once, when first asked
/// for (by the stream's thread or by the caller). Thread-safe.
class FeedScene {
 public:
  explicit FeedScene(scene message) : message_(std::move(message)) {}
  FeedScene(const FeedScene&) = delete;
  FeedScene& operator=(const FeedScene&) = delete;

  const scene& message() const { return message_; }

  /// The colour (RGB, CV_8UC3) or gray (CV_8UC1) image. Throws FeedError if it does not decode.
  cv::Mat Color();
  /// The depth image as stored (CV_16UC1; mm = value * camera.depth_scale_mm). Throws FeedError
  /// if the scene has none or it does not decode.
  cv::Mat Depth();
  /// The instance map (CV_16UC1, 0 = background, else the instance_id). Throws FeedError.
  cv::Mat InstanceMap();
  /// Whether the scene carries a depth image.
  bool has_depth() const { return message_.depth.size > 0; }
  /// The 3D camera's depth (config sensor_3d; CV_16UC1, mm = value * camera.depth_scale_mm,
  /// 0 = no depth). Throws FeedError if the scene has none or it does not decode.
  cv::Mat DepthSensor();
  /// Whether the scene carries a 3D camera's depth.
  bool has_depth_sensor() const { return message_.depth_sensor.size > 0; }

  /// How many times the stream handed this same scene out before (a recording that repeats a
  /// scene for each use; 0 otherwise).
  int64_t occurrence = 0;

  /// Decodes the images asked for (depth: both depths the scene has; those already decoded are
  /// kept) and marks the scene
  /// prepared: ready when they decoded, failed with the reason otherwise. Never throws.
  void Prepare(bool color, bool depth, bool instance_map);
  /// Marks the scene failed with `why` (it will not be prepared).
  void Fail(const std::string& why);
  /// Waits until Prepare (or Fail) has run; true when the scene is ready, false (the reason in
  /// `*why`) when an image did not decode.
  bool WaitPrepared(std::string* why);

 private:
  cv::Mat Decoded(std::optional<cv::Mat>* slot, const image& message, const std::string& field);

  scene message_;
  std::mutex mutex_;
  std::optional<cv::Mat> color_;
  std::optional<cv::Mat> depth_;
  std::optional<cv::Mat> instance_map_;
  std::optional<cv::Mat> depth_sensor_;
  // Prepare's outcome: 0 not yet, 1 ready, 2 failed (`failure` says why)
  std::mutex prepared_mutex_;
  std::condition_variable prepared_changed_;
  int prepared_ = 0;
  std::string failure_;
};

}  // namespace stackgen::feed
