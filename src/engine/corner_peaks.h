// Shi and Tomasi's corners ("Good features to track", 1994) as the tracker tops its points up
// with them: the smaller eigenvalue of each pixel's 3 x 3 sum of gradient products, and the
// pixels where it is largest within 5 x 5.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct CornerPeak {
  float response;  // the smaller eigenvalue, on cv::cornerMinEigenVal(gray, 3, 3)'s scale
  int x, y;
};

// The pixels of `gray` (8-bit) in rows and columns [border, size - border) (border >= 3) whose response is
// above `least` and not below any within 5 x 5 (what cv::cornerMinEigenVal(gray, 3, 3) and
// cv::dilate twice with 3 x 3 give), in raster order. Gradients are Sobel's 3 x 3 scaled by
// 1 / (4 x 3 x 255), as OpenCV scales them; their sums are exact (integers), so a response
// differs from OpenCV's only by the rounding of its last steps. One pass over the image, where
// OpenCV makes six, sixteen pixels at a time on AVX-512.
std::vector<CornerPeak> CornerPeaks(const cv::Mat& gray, int border, float least);

namespace internal {
// The same, one pixel at a time (CPUs without AVX-512): the same values to the bit.
std::vector<CornerPeak> CornerPeaksScalar(const cv::Mat& gray, int border, float least);
}  // namespace internal

}  // namespace rolamos
