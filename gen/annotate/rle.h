#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "contract/rle.h"

namespace stackgen {

// COCO run-length encoding of binary masks as OpenCV matrices, exactly as cocoapi
// common/maskApi.c: the mask is read column by column (Fortran order), runs alternate zeros and
// ones and start with the count of zeros (0 when the first pixel is set). The compressed string
// form (RunsToString, StringToRuns) is contract/rle.h's, which consumers share.

/// Runs of `mask` (CV_8UC1, nonzero = inside), column-major, starting with zeros. An empty (0x0)
/// mask gives {0}, as rleEncode. Throws std::runtime_error if `mask` is not CV_8UC1.
std::vector<uint32_t> MaskToRuns(const cv::Mat& mask);

/// The CV_8UC1 mask (255 inside, 0 outside) of `height` x `width` pixels that `runs` describe.
/// Throws std::runtime_error if the runs do not add up to height * width or a size is negative.
cv::Mat RunsToMask(const std::vector<uint32_t>& runs, int height, int width);

/// The compressed RLE string of `mask` (CV_8UC1, nonzero = inside). Throws as MaskToRuns.
std::string EncodeRle(const cv::Mat& mask);

/// The mask (CV_8UC1, 255 inside) of a compressed RLE string over `height` x `width` pixels.
/// Throws as StringToRuns and RunsToMask.
cv::Mat DecodeRle(const std::string& counts, int height, int width);

/// Pixels inside (the sum of the ones runs) of a compressed RLE string. Throws as StringToRuns.
uint64_t RleArea(const std::string& counts);

/// Box [x, y, width, height] in pixels of the runs, as maskApi rleToBbox: all zero for an empty
/// mask; a ones run that wraps into the next column spans the full height.
/// Throws std::runtime_error if the runs do not add up to height * width.
std::array<int, 4> RunsBbox(const std::vector<uint32_t>& runs, int height, int width);

/// Box [x, y, width, height] of a compressed RLE string over `height` x `width` pixels, as
/// RunsBbox. Throws as StringToRuns and RunsBbox.
std::array<int, 4> RleBbox(const std::string& counts, int height, int width);

}  // namespace stackgen
