#include "consumers/dataset/images.h"

#include <zlib.h>

#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

namespace stackgen {
namespace {

// a 24 x 16 RGB image whose channels differ, so that an RGB/BGR swap shows
cv::Mat Colours() {
  cv::Mat pixels(16, 24, CV_8UC3);
  for (int y = 0; y < pixels.rows; ++y) {
    for (int x = 0; x < pixels.cols; ++x) {
      pixels.at<cv::Vec3b>(y, x) =
          cv::Vec3b(static_cast<uint8_t>(10 * x), static_cast<uint8_t>(7 * y), 200);
    }
  }
  return pixels;
}

image Message(const std::vector<uint8_t>& png, const cv::Mat& pixels) {
  image m{};
  m.width = pixels.cols;
  m.height = pixels.rows;
  m.pixel_format = pixels.type() == CV_8UC3   ? image::PIXEL_RGB8
                   : pixels.type() == CV_8UC1 ? image::PIXEL_GRAY8
                                              : image::PIXEL_DEPTH16;
  m.encoding = image::ENCODING_PNG;
  m.data = png;
  m.size = static_cast<int32_t>(png.size());
  return m;
}

// `png` with a tEXt chunk after IHDR; its CRC (zlib's crc32 over type and data) plus `crc_error`
std::vector<uint8_t> WithTextChunk(const std::vector<uint8_t>& png, uint32_t crc_error) {
  const std::string body = std::string("tEXt") + "Comment" + '\0' + "made by a test";
  const uint32_t length = static_cast<uint32_t>(body.size() - 4);
  const uint32_t crc = static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(body.data()),
                                                   static_cast<uInt>(body.size()))) +
                       crc_error;
  std::vector<uint8_t> chunk;
  for (int shift = 24; shift >= 0; shift -= 8)
    chunk.push_back(static_cast<uint8_t>(length >> shift));
  chunk.insert(chunk.end(), body.begin(), body.end());
  for (int shift = 24; shift >= 0; shift -= 8) chunk.push_back(static_cast<uint8_t>(crc >> shift));
  std::vector<uint8_t> out = png;
  const size_t after_ihdr = 8 + 4 + 4 + 13 + 4;  // signature, IHDR length, type, data, CRC
  out.insert(out.begin() + static_cast<std::ptrdiff_t>(after_ihdr), chunk.begin(), chunk.end());
  return out;
}

// RGB, gray and 16-bit PNGs decode to their pixels, RGB in RGB order; encoding leaves the
// pixels as they were (it used to swap an RGB matrix to BGR in place: a RAW image's decoded
// matrix shows the message's own bytes).
TEST(DecodeImageTest, PngsDecodeToTheirPixels) {
  const cv::Mat rgb = Colours();
  const cv::Mat original = rgb.clone();
  cv::Mat gray(9, 7, CV_8UC1), depth(9, 7, CV_16UC1);
  cv::randu(gray, 0, 255);
  cv::randu(depth, 0, 65535);
  for (const cv::Mat& pixels : {rgb, gray, depth}) {
    SCOPED_TRACE(pixels.type());
    std::string why;
    const cv::Mat decoded = DecodeImage(Message(EncodeImage(pixels, 3), pixels), &why);
    ASSERT_FALSE(decoded.empty()) << why;
    EXPECT_EQ(decoded.type(), pixels.type());
    EXPECT_EQ(cv::norm(decoded, pixels, cv::NORM_INF), 0.0);
  }
  EXPECT_EQ(cv::norm(rgb, original, cv::NORM_INF), 0.0);
}

// A PNG whose ancillary chunk has a bad CRC is refused (OpenCV reads it: libpng only warns), as
// are bytes after IEND, a cut, and a flipped bit in the image data; libpng prints nothing. With
// the right CRC the same chunk is fine.
TEST(DecodeImageTest, EveryChunkIsCheckedWithoutAPrint) {
  const cv::Mat pixels = Colours();
  const std::vector<uint8_t> png = EncodeImage(pixels, 3);
  std::string why;
  ASSERT_FALSE(DecodeImage(Message(WithTextChunk(png, 0), pixels), &why).empty()) << why;

  const std::vector<uint8_t> bad_crc = WithTextChunk(png, 1);
  EXPECT_FALSE(cv::imdecode(bad_crc, cv::IMREAD_UNCHANGED).empty())
      << "OpenCV refuses it too: this test no longer shows the difference";
  std::vector<uint8_t> trailing = png;
  trailing.push_back(0);
  const std::vector<uint8_t> cut(png.begin(), png.end() - 20);
  std::vector<uint8_t> flipped = png;
  flipped[png.size() / 2] ^= 0x04;

  ::testing::internal::CaptureStderr();
  for (const auto& [bytes, expected] : std::vector<std::pair<std::vector<uint8_t>, std::string>>{
           {bad_crc, "CRC"},
           {trailing, "bytes follow its IEND"},
           {cut, "ends too early"},
           {flipped, ""}}) {
    why.clear();
    EXPECT_TRUE(DecodeImage(Message(bytes, pixels), &why).empty());
    EXPECT_NE(why.find("does not decode as a whole PNG image of 24 x 16 x 3"), std::string::npos)
        << why;
    EXPECT_NE(why.find(expected), std::string::npos) << why;
  }
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

}  // namespace
}  // namespace stackgen
