#include "consumers/feed/scene_data.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/bus.h"
#include "consumers/dataset/images.h"
#include "contract/rle.h"
#include "contract/scene_contract.h"

namespace stackgen::feed {
namespace {

bool Refuse(const std::string& reason, std::string* why) {
  if (why != nullptr) *why = reason;
  return false;
}

}  // namespace

cv::Mat DecodeImage(const image& message, const std::string& field) {
  if (message.size == 0) throw FeedError("the scene has no " + field + " image");
  // the consumers' one decoder (consumers/dataset/images.h)
  std::string why;
  cv::Mat decoded = stackgen::DecodeImage(message, &why);
  if (decoded.empty()) throw FeedError(field + " does not decode: " + why);
  return decoded;
}

bool CheckFeedScene(const scene& message, std::string* why) {
  // the contract every consumer checks, and an instance map: a learner's masks come from it
  if (!stackgen::CheckScene(message, why)) return false;
  if (message.instance_map.size == 0) return Refuse("the scene has no instance_map image", why);
  return true;
}

cv::Mat FeedScene::Decoded(std::optional<cv::Mat>* slot, const image& message,
                           const std::string& field) {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (!slot->has_value()) {
    try {
      *slot = DecodeImage(message, field);
    } catch (const FeedError& error) {
      throw FeedError("scene " + std::to_string(message_.header.generator_id) + "/" +
                      std::to_string(message_.header.seq) + ": " + error.what());
    }
  }
  return **slot;
}

void FeedScene::Prepare(bool color, bool depth, bool instance_map) {
  std::string why;
  try {
    if (color) Color();
    if (instance_map) InstanceMap();
    if (depth && has_depth()) Depth();
    if (depth && has_depth_sensor()) DepthSensor();
  } catch (const std::exception& error) {
    why = error.what();
  }
  if (!why.empty()) {
    Fail(why);
    return;
  }
  {
    const std::lock_guard<std::mutex> lock(prepared_mutex_);
    prepared_ = 1;
  }
  prepared_changed_.notify_all();
}

void FeedScene::Fail(const std::string& why) {
  {
    const std::lock_guard<std::mutex> lock(prepared_mutex_);
    prepared_ = 2;
    failure_ = why;
  }
  prepared_changed_.notify_all();
}

bool FeedScene::WaitPrepared(std::string* why) {
  std::unique_lock<std::mutex> lock(prepared_mutex_);
  prepared_changed_.wait(lock, [this] { return prepared_ != 0; });
  if (prepared_ == 2 && why != nullptr) *why = failure_;
  return prepared_ == 1;
}

cv::Mat FeedScene::Color() { return Decoded(&color_, message_.color, "color"); }
cv::Mat FeedScene::Depth() { return Decoded(&depth_, message_.depth, "depth"); }
cv::Mat FeedScene::DepthSensor() {
  return Decoded(&depth_sensor_, message_.depth_sensor, "depth_sensor");
}
cv::Mat FeedScene::InstanceMap() {
  return Decoded(&instance_map_, message_.instance_map, "instance_map");
}

std::unique_ptr<Bus> OpenBus(const std::string& url, const std::string& key_file, bool open_bus) {
  try {
    BusOptions options;
    options.key_file = key_file;
    options.open_bus = open_bus;
    return std::make_unique<Bus>(ResolveLcmUrl(url), options);
  } catch (const std::exception& error) {
    throw FeedError(error.what());
  }
}

}  // namespace stackgen::feed
