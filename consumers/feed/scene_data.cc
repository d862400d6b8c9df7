#include "consumers/feed/scene_data.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/bounded_decode.h"
#include "bus/rle.h"
#include "bus/scene_contract.h"

namespace stackgen::feed {
namespace {

bool Refuse(const std::string& reason, std::string* why) {
  if (why != nullptr) *why = reason;
  return false;
}

}  // namespace

cv::Mat DecodeImage(const image& message, const std::string& field) {
  std::string problem;
  if (message.size == 0) throw FeedError("the scene has no " + field + " image");
  if (!CheckEncodedImageDims(message, &problem)) throw FeedError(field + ": " + problem);
  const bool sixteen = message.pixel_format == image::PIXEL_DEPTH16 ||
                       message.pixel_format == image::PIXEL_INSTANCE16;
  const bool rgb = message.pixel_format == image::PIXEL_RGB8;
  const int type = sixteen ? CV_16UC1 : rgb ? CV_8UC3 : CV_8UC1;
  if (message.encoding == image::ENCODING_RAW) {
    // little-endian 16-bit values are this machine's order (x86-64, arm64)
    return cv::Mat(message.height, message.width, type, const_cast<uint8_t*>(message.data.data()));
  }
  const cv::Mat bytes(1, message.size, CV_8UC1, const_cast<uint8_t*>(message.data.data()));
  cv::Mat decoded;
  try {
    decoded = cv::imdecode(bytes, sixteen ? cv::IMREAD_UNCHANGED
                                  : rgb   ? cv::IMREAD_COLOR
                                          : cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception& error) {
    throw FeedError(field + " does not decode: " + error.what());
  }
  if (decoded.empty() || decoded.type() != type || decoded.rows != message.height ||
      decoded.cols != message.width) {
    throw FeedError(field + " does not decode to a " + std::to_string(message.width) + "x" +
                    std::to_string(message.height) + " image of its pixel_format");
  }
  if (rgb) cv::cvtColor(decoded, decoded, cv::COLOR_BGR2RGB);
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
cv::Mat FeedScene::InstanceMap() {
  return Decoded(&instance_map_, message_.instance_map, "instance_map");
}

}  // namespace stackgen::feed
