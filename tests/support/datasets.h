#pragma once

// Test helpers for COCO dataset folders written by stackgen-coco: counting the images stored
// and comparing two datasets whole (the end-to-end tests check every dataset against a clean
// run's).

#include <chrono>
#include <filesystem>
#include <map>
#include <string>
#include <thread>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tests/support/process.h"

namespace stackgen {
namespace testing {

/// Images (not .tmp) in a dataset folder's images/; 0 when there is none.
inline int ImagesStored(const std::string& dataset) {
  std::error_code error;
  int count = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dataset + "/images", error)) {
    if (entry.path().extension() != ".tmp") ++count;
  }
  return count;
}

/// Waits until the dataset holds `count` images; false after `timeout_s`.
inline bool WaitForImages(const std::string& dataset, int count, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < deadline) {
    if (ImagesStored(dataset) >= count) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

/// The dataset's annotations.json without "info" (which names the folder and the time).
inline nlohmann::json DatasetAnnotations(const std::string& dataset) {
  nlohmann::json parsed = nlohmann::json::parse(ReadFile(dataset + "/annotations.json"));
  parsed.erase("info");
  return parsed;
}

/// Expects `expected` to hold `images` images and `actual` the same annotations ("info" aside)
/// and the same image files, byte for byte.
inline void ExpectSameDataset(const std::string& expected, const std::string& actual,
                              size_t images) {
  namespace fs = std::filesystem;
  const nlohmann::json a = DatasetAnnotations(expected), b = DatasetAnnotations(actual);
  EXPECT_EQ(a["images"].size(), images);
  EXPECT_EQ(a, b) << actual << " differs from " << expected;
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::directory_iterator(expected + "/images")) {
    files[entry.path().filename()] = ReadFile(entry.path());
  }
  int compared = 0;
  for (const auto& entry : fs::directory_iterator(actual + "/images")) {
    const std::string name = entry.path().filename();
    ASSERT_EQ(files.count(name), 1u) << "extra file " << name << " in " << actual;
    EXPECT_TRUE(files[name] == ReadFile(entry.path())) << name << " differs";
    ++compared;
  }
  EXPECT_EQ(compared, static_cast<int>(files.size()));
}

/// Every file of a dataset folder but those named `skip` (a journal), by path relative to it,
/// with its bytes.
inline std::map<std::string, std::string> DatasetFiles(const std::string& dataset,
                                                       const std::string& skip) {
  namespace fs = std::filesystem;
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dataset)) {
    if (!entry.is_regular_file() || entry.path().filename() == skip) continue;
    files[fs::relative(entry.path(), dataset).string()] = ReadFile(entry.path().string());
  }
  return files;
}

}  // namespace testing
}  // namespace stackgen
