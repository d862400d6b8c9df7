#include "consumers/dataset/images.h"

#include <png.h>

#include <csetjmp>
#include <cstring>
#include <stdexcept>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "contract/bounded_decode.h"

namespace stackgen {
namespace {

// what libpng reads from and says while it decodes one PNG held in memory
struct PngSource {
  const uint8_t* data = nullptr;
  size_t size = 0;
  size_t offset = 0;
  std::string error;  // libpng's error message, when it stopped
};

void ReadPngBytes(png_structp png, png_bytep out, size_t length) {
  PngSource* source = static_cast<PngSource*>(png_get_io_ptr(png));
  if (length > source->size - source->offset) png_error(png, "the file ends too early");
  std::memcpy(out, source->data + source->offset, length);
  source->offset += length;
}

// libpng's errors are kept (not printed) and end the decoding; its warnings are dropped: what
// matters is refused as an error (the CRC actions below)
void OnPngError(png_structp png, png_const_charp message) {
  static_cast<PngSource*>(png_get_error_ptr(png))->error = message;
  png_longjmp(png, 1);
}

void OnPngWarning(png_structp, png_const_charp) {}

// reads the PNG of `source` into `*pixels` (made of `type`) through `rows`; false when libpng
// stopped (its message in source->error). Everything it changes lives in the caller's frame, and
// nothing here has a destructor: libpng's errors longjmp back to the setjmp below.
bool ReadPng(png_structp png, png_infop info, int type, cv::Mat* pixels,
             std::vector<png_bytep>* rows) {
  if (setjmp(png_jmpbuf(png)) != 0) return false;
  png_set_crc_action(png, PNG_CRC_ERROR_QUIT, PNG_CRC_ERROR_QUIT);
  png_read_info(png, info);
  const png_uint_32 width = png_get_image_width(png, info);
  const png_uint_32 height = png_get_image_height(png, info);
  const int depth = png_get_bit_depth(png, info);
  const int color = png_get_color_type(png, info);
  const bool fits = (type == CV_8UC3 && color == PNG_COLOR_TYPE_RGB && depth == 8) ||
                    (type == CV_8UC1 && color == PNG_COLOR_TYPE_GRAY && depth == 8) ||
                    (type == CV_16UC1 && color == PNG_COLOR_TYPE_GRAY && depth == 16);
  if (!fits) png_error(png, "another pixel format than the message declares");
  // 16-bit samples are big-endian in PNG, little-endian here (x86-64, arm64)
  if (depth == 16) png_set_swap(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  pixels->create(static_cast<int>(height), static_cast<int>(width), type);
  rows->resize(height);
  for (png_uint_32 y = 0; y < height; ++y) (*rows)[y] = pixels->ptr(static_cast<int>(y));
  png_read_image(png, rows->data());
  png_read_end(png, info);
  const PngSource* source = static_cast<const PngSource*>(png_get_io_ptr(png));
  if (source->offset != source->size) png_error(png, "bytes follow its IEND chunk");
  return true;
}

// `data` as a whole PNG of `type` (CV_8UC3 in RGB order, CV_8UC1, CV_16UC1), read by libpng with
// every chunk's CRC checked (ancillary chunks too: libpng only warns about theirs by default)
// and zlib's checksum of the image data, to its IEND with nothing after; empty with `*why` when
// anything is wrong. Nothing is printed.
cv::Mat DecodePng(const std::vector<uint8_t>& data, int type, std::string* why) {
  PngSource source;
  source.data = data.data();
  source.size = data.size();
  png_structp png =
      png_create_read_struct(PNG_LIBPNG_VER_STRING, &source, OnPngError, OnPngWarning);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    if (why != nullptr) *why = "libpng cannot start (out of memory)";
    return cv::Mat();
  }
  png_set_read_fn(png, &source, ReadPngBytes);
  cv::Mat pixels;
  std::vector<png_bytep> rows;
  const bool read = ReadPng(png, info, type, &pixels, &rows);
  png_destroy_read_struct(&png, &info, nullptr);
  if (!read) {
    if (why != nullptr) *why = source.error;
    return cv::Mat();
  }
  return pixels;
}

}  // namespace

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
  std::string png_error;  // libpng's words, when it refused the data
  if (m.encoding == image::ENCODING_RAW) {
    const size_t bytes = static_cast<size_t>(m.width) * m.height * CV_ELEM_SIZE(type);
    if (m.width > 0 && m.height > 0 && m.data.size() == bytes) {
      // little-endian 16-bit values are this machine's order (x86-64, arm64)
      decoded = cv::Mat(m.height, m.width, type, const_cast<uint8_t*>(m.data.data()));
    }
  } else if (m.encoding == image::ENCODING_PNG) {
    decoded = DecodePng(m.data, type, &png_error);
  } else {
    const bool jpeg_ends =
        m.data.size() >= 2 && m.data[m.data.size() - 2] == 0xff && m.data.back() == 0xd9;
    if (jpeg_ends) {
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
             " (damaged or cut short" + (png_error.empty() ? "" : ": " + png_error) + ")";
    }
    return cv::Mat();
  }
  return decoded;
}

std::vector<uint8_t> EncodeImage(const cv::Mat& pixels, int compression, int jpeg_quality) {
  // a new matrix for the BGR order OpenCV writes from: `pixels` may show a message's bytes
  cv::Mat to_encode;
  if (pixels.type() == CV_8UC3) {
    cv::cvtColor(pixels, to_encode, cv::COLOR_RGB2BGR);
  } else {
    to_encode = pixels;
  }
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
