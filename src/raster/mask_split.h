// A masked tile's two parts: the colour JPEG stores and the mask's packed bits (the store's
// format: docs/store-format.md). Patch images are written as RGBA tiles whose alpha marks where
// the patch has data; the writer splits every tile of every level. OpenCV's six passes over a
// tile (the alpha extracted, compared, the colour channels mixed out, counted, averaged, filled)
// were 40 % of the tile encoding's CPU on 1292 x 964 stills; here one pass, and a second over
// the tiles that are partly data, sixteen pixels at a time where the CPU has AVX-512: the same
// bytes (mask_split_test.cc).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// Splits a file-order tile with alpha (RGBA or grey + alpha, 8-bit, a width that is a multiple
// of 8) into `colour` (RGB or grey) and `bits` (a row's bits packed 8 to a byte, the first pixel
// in the highest bit; 1 where alpha >= 128, data). Pixels without data take the mean colour of
// those with data (cv::mean's, rounded), so JPEG's blocks do not ring with black along the
// data's edge.
void SplitMask(const cv::Mat& tile, cv::Mat* colour, cv::Mat* bits);

}  // namespace rolamos
