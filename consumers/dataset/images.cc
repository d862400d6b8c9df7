#include "consumers/dataset/images.h"

#include <stdexcept>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bus/bounded_decode.h"

namespace stackgen {

cv::Mat DecodeImage(const image& m, std::string* why) {
  if (m.size == 0 || m.data.empty()) {
    if (why != nullptr) *why = "has no image data";
    return cv::Mat();
  }
  if (!CheckEncodedImageDims(m, why)) return cv::Mat();
  const int type = m.pixel_format == image::PIXEL_RGB8    ? CV_8UC3
                   : m.pixel_format == image::PIXEL_GRAY8 ? CV_8UC1
                                                          : CV_16UC1;
  const char* format = m.encoding == image::ENCODING_PNG    ? "PNG"
                       : m.encoding == image::ENCODING_JPEG ? "JPEG"
                                                            : "RAW";
  cv::Mat decoded;
  if (m.encoding == image::ENCODING_RAW) {
    const size_t bytes = static_cast<size_t>(m.width) * m.height * CV_ELEM_SIZE(type);
    if (m.width > 0 && m.height > 0 && m.data.size() == bytes) {
      // little-endian 16-bit values are this machine's order (x86-64, arm64)
      decoded = cv::Mat(m.height, m.width, type, const_cast<uint8_t*>(m.data.data()));
    }
  } else {
    const bool png = m.encoding == image::ENCODING_PNG;
    const bool jpeg_ends = m.encoding == image::ENCODING_JPEG && m.data.size() >= 2 &&
                           m.data[m.data.size() - 2] == 0xff && m.data.back() == 0xd9;
    if (png || jpeg_ends) {
      try {
        decoded = cv::imdecode(m.data, cv::IMREAD_UNCHANGED);
      } catch (const cv::Exception&) {
        decoded = cv::Mat();
      }
      if (!decoded.empty() && decoded.type() == CV_8UC3) {
        cv::cvtColor(decoded, decoded, cv::COLOR_BGR2RGB);
      }
    }
  }
  if (decoded.empty() || decoded.cols != m.width || decoded.rows != m.height ||
      decoded.type() != type) {
    if (why != nullptr) {
      *why = std::string("data does not decode as a whole ") + format + " image of " +
             std::to_string(m.width) + " x " + std::to_string(m.height) + " x " +
             std::to_string(CV_MAT_CN(type)) + (CV_MAT_DEPTH(type) == CV_16U ? " uint16" : "") +
             " (damaged or cut short)";
    }
    return cv::Mat();
  }
  return decoded;
}

std::vector<uint8_t> EncodeImage(const cv::Mat& pixels, int compression, int jpeg_quality) {
  cv::Mat to_encode = pixels;
  if (pixels.type() == CV_8UC3) cv::cvtColor(pixels, to_encode, cv::COLOR_RGB2BGR);
  std::vector<uint8_t> bytes;
  const bool jpeg = jpeg_quality > 0;
  std::vector<int> parameters;
  if (jpeg) {
    parameters = {cv::IMWRITE_JPEG_QUALITY, jpeg_quality};
  } else if (compression >= 0) {
    parameters = {cv::IMWRITE_PNG_COMPRESSION, compression};
  }
  if (!cv::imencode(jpeg ? ".jpg" : ".png", to_encode, bytes, parameters)) {
    throw std::runtime_error(std::string("cannot encode an image as ") + (jpeg ? "JPEG" : "PNG"));
  }
  return bytes;
}

}  // namespace stackgen
