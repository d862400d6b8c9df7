#pragma once
// The images of a scene message as OpenCV matrices, decoded whole, for the dataset writers.

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <stackgen/image.hpp>

namespace stackgen {

/// Decodes `image` (RAW, PNG or JPEG) whole into a matrix of its pixel format: CV_8UC3 in RGB
/// order (not OpenCV's BGR), CV_8UC1, or CV_16UC1. A RAW image is not copied: the matrix shows
/// the message's bytes (clone it to keep it longer than the message). The one image decoder of
/// the consumers (dataset writers and the Python feed). Returns an empty matrix and one line in
/// `*why` when the image has no data or does not decode to exactly its declared size and format:
/// its PNG or JPEG header is checked first (CheckEncodedImageDims: the header decides how much
/// is allocated), then a PNG is read by libpng itself with every chunk's CRC checked, ancillary
/// ones too (OpenCV lets libpng only warn about those), zlib's checksum of the image data, the
/// IEND chunk and nothing after it, so a flipped bit or a cut shows, and libpng prints nothing;
/// a JPEG (OpenCV) must also end with its end-of-image marker, as libjpeg fills a cut one with
/// grey.
cv::Mat DecodeImage(const image& image, std::string* why);

/// `pixels` (CV_8UC3 in RGB order, CV_8UC1 or CV_16UC1) as a PNG file with zlib level
/// `compression` (0..9; -1: OpenCV's default, level 1 with its RLE strategy), or a JPEG file of
/// `jpeg_quality` (1..100) when that is above 0. Throws std::runtime_error if OpenCV cannot encode
/// it.
std::vector<uint8_t> EncodeImage(const cv::Mat& pixels, int compression, int jpeg_quality = 0);

}  // namespace stackgen
