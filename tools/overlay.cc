// stackgen-overlay: draws the masks, boxes and ids of one image of a COCO dataset written by
// stackgen-coco over the image, for a quick look (the README's example image).

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/flags.h"
#include "gen/annotate/rle.h"

namespace {

constexpr const char* kUsage = R"(usage: stackgen-overlay DATASET_DIR OUT.png [--image N]

Draws every annotation of image N (default 0: the first in annotations.json) of a COCO dataset
written by stackgen-coco: each visible mask tinted in its own colour with its outline, its box
and its instance id and visible fraction.
)";

int Run(int argc, char** argv) {
  // the command line: a bad one is one line and exit status 2
  std::vector<std::string> paths;
  int64_t image = 0;
  stackgen::FlagParser parser("stackgen-overlay");
  parser.Positional(&paths, "path", 2, 2);  // DATASET_DIR OUT.png
  parser.Int("--image", &image, 0, INT32_MAX);
  parser.ParseOrExit(argc, argv, [] { std::printf("%s", kUsage); });
  const std::string dir = paths[0];
  const std::string out = paths[1];
  const size_t index = static_cast<size_t>(image);

  // the dataset and the chosen image.
  std::ifstream file(dir + "/annotations.json");
  if (!file) throw std::runtime_error(dir + "/annotations.json: cannot read");
  const nlohmann::json dataset = nlohmann::json::parse(file);
  if (index >= dataset["images"].size()) {
    throw std::runtime_error(dir + "/annotations.json: no image " + std::to_string(index));
  }
  const nlohmann::json& record = dataset["images"][index];
  const std::string path = dir + "/images/" + record["file_name"].get<std::string>();
  cv::Mat picture = cv::imread(path, cv::IMREAD_COLOR);
  if (picture.empty()) throw std::runtime_error(path + ": cannot read");

  // each mask tinted, outlined and labelled.
  const int64_t image_id = record["id"].get<int64_t>();
  cv::Mat tint = picture.clone();
  int drawn = 0;
  std::vector<std::pair<cv::Mat, cv::Scalar>> outlines;
  for (const nlohmann::json& annotation : dataset["annotations"]) {
    if (annotation["image_id"].get<int64_t>() != image_id) continue;
    const cv::Mat mask = stackgen::DecodeRle(
        annotation["segmentation"]["counts"].get<std::string>(), picture.rows, picture.cols);
    const int id = annotation.value("instance_id", drawn + 1);
    const cv::Scalar colour((id * 67) % 200 + 55, (id * 131) % 200 + 55, (id * 29) % 200 + 55);
    tint.setTo(colour, mask);
    outlines.emplace_back(mask, colour);
    ++drawn;
  }
  cv::addWeighted(picture, 0.55, tint, 0.45, 0, picture);
  for (const nlohmann::json& annotation : dataset["annotations"]) {
    if (annotation["image_id"].get<int64_t>() != image_id) continue;
    const nlohmann::json& box = annotation["bbox"];
    const cv::Rect rect(box[0].get<int>(), box[1].get<int>(), box[2].get<int>(), box[3].get<int>());
    cv::rectangle(picture, rect, cv::Scalar(255, 255, 255), 1);
    char label[64];
    std::snprintf(label, sizeof(label), "%d %.2f", annotation.value("instance_id", 0),
                  annotation.value("visib_fract", 1.0));
    cv::putText(picture, label, rect.tl() + cv::Point(2, 12), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  for (const auto& [mask, colour] : outlines) {
    std::vector<std::vector<cv::Point>> contours;
    cv::findContours(mask, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
    cv::drawContours(picture, contours, -1, colour, 2, cv::LINE_AA);
  }
  if (!cv::imwrite(out, picture)) throw std::runtime_error(out + ": cannot write");
  std::printf("stackgen-overlay: %s: %d annotations of %s\n", out.c_str(), drawn, path.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "stackgen-overlay: error: %s\n", error.what());
    return 1;
  }
}
