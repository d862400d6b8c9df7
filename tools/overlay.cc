// stackgen-overlay: draws the masks, boxes and ids of one image of a COCO dataset written by
// stackgen-coco over the image, for a quick look (the README's example image, docs/example.png).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "cli/flags.h"
#include "gen/annotate/rle.h"

namespace {

constexpr const char* kUsage = R"(usage: stackgen-overlay DATASET_DIR OUT.png [--image N]

Draws every annotation of image N (default 0: the first in annotations.json) of a COCO dataset
written by stackgen-coco: each visible mask tinted in its own colour with its outline, its box
and its instance id and visible fraction; and its suction grasps (config grasps), each a dot
with a 15 mm line along the surface's normal: green where the cup seals fully and the tool
comes in, yellow where it seals but the approach is blocked, red where it does not seal; the
best of each part ringed in white, a proven one filled (lifted) or crossed (dropped, stuck);
and its parallel-jaw grasps (grasps.parallel_jaw), each a line between its two contacts with a
square at each finger, blue where the fingers come in, violet where they are blocked, the best
thicker, a proven one with a dot (lifted) or a cross at its middle.
)";

// The error for an annotation of image `image_id` in `json_path`: names it and says `what`.
std::runtime_error AnnotationError(const std::string& json_path, int64_t image_id,
                                   const nlohmann::json& annotation, const std::string& what) {
  return std::runtime_error(json_path + ": annotation " +
                            annotation.value("id", nlohmann::json()).dump() + " (image " +
                            std::to_string(image_id) + "): " + what);
}

// The COCO file `json_path`, with its images and annotations arrays.
nlohmann::json ReadDataset(const std::string& json_path) {
  std::ifstream file(json_path);
  if (!file) throw std::runtime_error(json_path + ": cannot read");
  nlohmann::json dataset;
  try {
    dataset = nlohmann::json::parse(file);
  } catch (const nlohmann::json::parse_error& error) {
    throw std::runtime_error(json_path + ": not valid JSON (at byte " + std::to_string(error.byte) +
                             ")");
  }
  if (!dataset.is_object() || !dataset.contains("images") || !dataset["images"].is_array() ||
      !dataset.contains("annotations") || !dataset["annotations"].is_array()) {
    throw std::runtime_error(json_path +
                             ": not a COCO dataset (\"images\" and \"annotations\" "
                             "arrays expected)");
  }
  return dataset;
}

// The annotations of image `image_id`, each with an RLE mask and a box (an error names it).
std::vector<const nlohmann::json*> AnnotationsOf(const nlohmann::json& dataset, int64_t image_id,
                                                 const std::string& json_path) {
  std::vector<const nlohmann::json*> of_image;
  for (const nlohmann::json& annotation : dataset["annotations"]) {
    const auto image = annotation.find("image_id");
    if (image == annotation.end() || !image->is_number_integer()) {
      throw AnnotationError(json_path, image_id, annotation,
                            "image_id is missing or not an integer");
    }
    if (image->get<int64_t>() != image_id) continue;
    const auto segmentation = annotation.find("segmentation");
    const auto bbox = annotation.find("bbox");
    if (segmentation == annotation.end() || !segmentation->is_object() ||
        !segmentation->contains("counts") || !(*segmentation)["counts"].is_string()) {
      throw AnnotationError(json_path, image_id, annotation,
                            "segmentation.counts is missing or not an RLE string");
    }
    if (bbox == annotation.end() || !bbox->is_array() || bbox->size() != 4 ||
        !std::all_of(bbox->begin(), bbox->end(),
                     [](const nlohmann::json& v) { return v.is_number(); })) {
      throw AnnotationError(json_path, image_id, annotation, "bbox is missing or not 4 numbers");
    }
    of_image.push_back(&annotation);
  }
  return of_image;
}

// Draws `annotations` over `picture`: each mask tinted in its own colour with its outline, its
// box, instance id and visible fraction; returns how many.
int Draw(const std::vector<const nlohmann::json*>& annotations, int64_t image_id,
         const std::string& json_path, cv::Mat* picture) {
  cv::Mat tint = picture->clone();
  int drawn = 0;
  std::vector<std::pair<cv::Mat, cv::Scalar>> outlines;
  for (const nlohmann::json* annotation_pointer : annotations) {
    const nlohmann::json& annotation = *annotation_pointer;
    cv::Mat mask;
    try {
      mask = stackgen::DecodeRle(annotation["segmentation"]["counts"].get<std::string>(),
                                 picture->rows, picture->cols);
    } catch (const std::exception& error) {
      throw AnnotationError(json_path, image_id, annotation,
                            std::string("segmentation.counts: ") + error.what());
    }
    const int id = annotation.value("instance_id", drawn + 1);
    const cv::Scalar colour((id * 67) % 200 + 55, (id * 131) % 200 + 55, (id * 29) % 200 + 55);
    tint.setTo(colour, mask);
    outlines.emplace_back(mask, colour);
    ++drawn;
  }
  cv::addWeighted(*picture, 0.55, tint, 0.45, 0, *picture);
  for (const nlohmann::json* annotation_pointer : annotations) {
    const nlohmann::json& annotation = *annotation_pointer;
    const nlohmann::json& box = annotation["bbox"];
    const cv::Rect rect(box[0].get<int>(), box[1].get<int>(), box[2].get<int>(), box[3].get<int>());
    cv::rectangle(*picture, rect, cv::Scalar(255, 255, 255), 1);
    char label[64];
    std::snprintf(label, sizeof(label), "%d %.2f", annotation.value("instance_id", 0),
                  annotation.value("visib_fract", 1.0));
    cv::putText(*picture, label, rect.tl() + cv::Point(2, 12), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  for (const auto& [mask, colour] : outlines) {
    std::vector<std::vector<cv::Point>> contours;
    cv::findContours(mask, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
    cv::drawContours(*picture, contours, -1, colour, 2, cv::LINE_AA);
  }
  return drawn;
}

// the image's camera as stackgen-coco writes it (its "stackgen" block's camera)
constexpr const char* kIntrinsics[] = {"fx", "fy", "cx", "cy"};

// Draws the suction and parallel-jaw grasps of `annotations` (their "stackgen" blocks) over
// `picture`, projected with the image's camera `camera` (its "stackgen" block's fx, fy, cx, cy);
// returns how many.
int DrawGrasps(const std::vector<const nlohmann::json*>& annotations, const nlohmann::json& camera,
               int64_t image_id, const std::string& json_path, cv::Mat* picture) {
  int drawn = 0;
  const double fx = camera.at("fx").get<double>(), fy = camera.at("fy").get<double>();
  const double cx = camera.at("cx").get<double>(), cy = camera.at("cy").get<double>();
  const auto project = [&](const std::vector<double>& p) {
    return cv::Point(static_cast<int>(std::lround(fx * p.at(0) / p.at(2) + cx)),
                     static_cast<int>(std::lround(fy * p.at(1) / p.at(2) + cy)));
  };
  for (const nlohmann::json* annotation_pointer : annotations) {
    const nlohmann::json& annotation = *annotation_pointer;
    if (!annotation.contains("stackgen")) continue;
    // parallel jaws: the closing line between the two contacts, ticks at the fingers
    const nlohmann::json& jaws =
        annotation["stackgen"].value("parallel_jaw_grasps", nlohmann::json::array());
    for (const nlohmann::json& grasp : jaws) {
      try {
        const cv::Point a = project(grasp.at("point_a_mm").get<std::vector<double>>());
        const cv::Point b = project(grasp.at("point_b_mm").get<std::vector<double>>());
        const bool clear = grasp.at("approach_clear").get<bool>();
        const cv::Scalar colour = clear ? cv::Scalar(255, 160, 60) : cv::Scalar(200, 120, 200);
        cv::line(*picture, a, b, colour, grasp.at("rank").get<int>() == 0 ? 2 : 1, cv::LINE_AA);
        for (const cv::Point& finger : {a, b}) {
          cv::drawMarker(*picture, finger, colour, cv::MARKER_SQUARE, 5, 1, cv::LINE_AA);
        }
        const std::string proof = grasp.value("proof", std::string("not tried"));
        if (proof == "lifted") cv::circle(*picture, (a + b) / 2, 3, colour, cv::FILLED);
        if (proof == "dropped" || proof == "stuck") {
          cv::drawMarker(*picture, (a + b) / 2, colour, cv::MARKER_TILTED_CROSS, 9, 1);
        }
      } catch (const nlohmann::json::exception& error) {
        throw AnnotationError(json_path, image_id, annotation,
                              std::string("stackgen.parallel_jaw_grasps: ") + error.what());
      }
      ++drawn;
    }
    const nlohmann::json& grasps =
        annotation["stackgen"].value("suction_grasps", nlohmann::json::array());
    for (const nlohmann::json& grasp : grasps) {
      try {
        const cv::Point at(grasp.at("u").get<int>(), grasp.at("v").get<int>());
        const bool sealed = grasp.at("seal").get<double>() >= 0.99;
        const bool clear = grasp.at("approach_clear").get<bool>();
        const cv::Scalar colour = !sealed ? cv::Scalar(60, 60, 255)
                                  : clear ? cv::Scalar(80, 230, 80)
                                          : cv::Scalar(40, 220, 240);
        // the normal, 15 mm of it, through the camera
        const std::vector<double> p = grasp.at("point_mm").get<std::vector<double>>();
        const std::vector<double> n = grasp.at("normal").get<std::vector<double>>();
        const double tip[3] = {p.at(0) + 15 * n.at(0), p.at(1) + 15 * n.at(1),
                               p.at(2) + 15 * n.at(2)};
        if (tip[2] > 1) {
          cv::line(*picture, at, project({tip[0], tip[1], tip[2]}), colour, 1, cv::LINE_AA);
        }
        const std::string proof = grasp.value("proof", std::string("not tried"));
        cv::circle(*picture, at, 3, colour, proof == "lifted" ? cv::FILLED : 1, cv::LINE_AA);
        if (proof == "dropped" || proof == "stuck") {
          cv::drawMarker(*picture, at, colour, cv::MARKER_TILTED_CROSS, 9, 1, cv::LINE_AA);
        }
        if (grasp.at("rank").get<int>() == 0) {
          cv::circle(*picture, at, 6, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
        }
      } catch (const nlohmann::json::exception& error) {
        throw AnnotationError(json_path, image_id, annotation,
                              std::string("stackgen.suction_grasps: ") + error.what());
      }
      ++drawn;
    }
  }
  return drawn;
}

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
  const std::string json_path = dir + "/annotations.json";
  const nlohmann::json dataset = ReadDataset(json_path);
  if (index >= dataset["images"].size()) {
    throw std::runtime_error(json_path + ": no image " + std::to_string(index) + " (it has " +
                             std::to_string(dataset["images"].size()) + ")");
  }
  const nlohmann::json& record = dataset["images"][index];
  const std::string where = json_path + ": images[" + std::to_string(index) + "]";
  if (!record.contains("file_name") || !record["file_name"].is_string() || !record.contains("id") ||
      !record["id"].is_number_integer()) {
    throw std::runtime_error(where + ": file_name or id is missing or of the wrong type");
  }
  const std::string path = dir + "/images/" + record["file_name"].get<std::string>();
  std::error_code missing;
  if (!std::filesystem::exists(path, missing)) {
    throw std::runtime_error(where + ": its image " + path + " does not exist");
  }
  cv::Mat picture = cv::imread(path, cv::IMREAD_COLOR);
  if (picture.empty()) throw std::runtime_error(path + ": cannot read (damaged or not an image)");

  // each mask tinted, outlined and labelled.
  const int64_t image_id = record["id"].get<int64_t>();
  const std::vector<const nlohmann::json*> of_image = AnnotationsOf(dataset, image_id, json_path);
  const int drawn = Draw(of_image, image_id, json_path, &picture);
  const nlohmann::json camera =
      record.contains("stackgen") ? record["stackgen"].value("camera", nlohmann::json())
                                  : nlohmann::json();
  const bool projects = camera.is_object() && std::all_of(kIntrinsics, kIntrinsics + 4,
                                                          [&](const char* key) {
                                                            return camera.contains(key) &&
                                                                   camera[key].is_number();
                                                          });
  const int grasps = projects ? DrawGrasps(of_image, camera, image_id, json_path, &picture) : 0;
  if (!cv::imwrite(out, picture)) throw std::runtime_error(out + ": cannot write");
  std::printf("stackgen-overlay: %s: %d annotations of %s\n", out.c_str(), drawn, path.c_str());
  if (grasps > 0) std::printf("stackgen-overlay: %d grasps drawn\n", grasps);
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
