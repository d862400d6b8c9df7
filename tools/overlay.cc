// stackgen-overlay: draws the masks, boxes and ids of one image of a COCO dataset written by
// stackgen-coco over the image, for a quick look (the README's example image).

#include <cstdio>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "gen/annotate/rle.h"

namespace {

constexpr const char* kUsage = R"(usage: stackgen-overlay DATASET_DIR OUT.png [--image N]

Draws every annotation of image N (default 0: the first in annotations.json) of a COCO dataset
written by stackgen-coco: each visible mask tinted in its own colour with its outline, its box
and its instance id and visible fraction.
)";

int Run(int argc, char** argv) {
  if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    std::printf("%s", kUsage);
    return 0;
  }
  if (argc != 3 && argc != 5) throw std::invalid_argument("expected DATASET_DIR OUT.png");
  const std::string dir = argv[1];
  const std::string out = argv[2];
  size_t index = 0;
  if (argc == 5) {
    if (std::string(argv[3]) != "--image") throw std::invalid_argument("unknown flag " + std::string(argv[3]));
    index = std::stoul(argv[4]);
  }

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
    const cv::Mat mask = stackgen::DecodeRle(annotation["segmentation"]["counts"].get<std::string>(),
                                             picture.rows, picture.cols);
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
