#pragma once

// The COCO run-length codec of the masks in scene messages (instance.mask_visib_rle,
// mask_obj_rle), in one place for the generator, which writes them (gen/annotate/rle.h adds the
// OpenCV masks), and every consumer, which reads them. As cocoapi common/maskApi.c: the mask is
// read column by column (Fortran order), runs alternate zeros and ones and start with the count
// of zeros; the compressed string form is rleToString/rleFrString.

#include <cstdint>
#include <string>
#include <vector>

namespace stackgen {

/// The compressed string of `runs` (rleToString: 5 bits per char, chars '0'..'o', counts from
/// the fourth on stored as the difference to the count two before).
std::string RunsToString(const std::vector<uint32_t>& runs);

/// The runs of a compressed string (rleFrString). Throws std::runtime_error naming the offset if
/// a char is outside '0'..'o', the string ends inside a number, a number has too many chars, or
/// a count comes out negative or above 2^32 - 1.
std::vector<uint32_t> StringToRuns(const std::string& counts);

/// Sets to 1 the pixels of the mask `counts` (compressed RLE over `height` x `width` pixels,
/// column-major as COCO) in `out`, a row-major height x width byte array that the caller has
/// zeroed. Returns the pixels set. Throws std::runtime_error if the runs do not cover exactly
/// height * width pixels or the string is malformed.
int64_t DecodeRleInto(const std::string& counts, int height, int width, uint8_t* out);

/// DecodeRleInto for the window of `window_width` x `window_height` pixels at (x0, y0) of the
/// mask only: `out` is that window, row-major, zeroed by the caller. Returns the pixels set in
/// the window. Throws as DecodeRleInto.
int64_t DecodeRleWindow(const std::string& counts, int height, int width, int x0, int y0,
                        int window_width, int window_height, uint8_t* out);

}  // namespace stackgen
