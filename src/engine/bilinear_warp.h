// The canvases' perspective warp: a frame with its feather code interleaved (BGRW, 8 or 16 bits)
// into a patch's pixels, bilinear, edge pixels repeated. The same as cv::warpPerspective(src,
// dst, M, size, INTER_LINEAR, BORDER_REPLICATE), three to six times faster on these images:
// OpenCV 4.6 computes each pixel's source in double, rounds it to 1/32 px, and its 16-bit remap
// is scalar; here the source positions are found eight at a time and each pixel is one vector
// interpolation (AVX2 where the CPU has it). Positions are not rounded to 1/32 px, so values
// differ from OpenCV's by what the image changes over 1/64 px.
#pragma once

#include <array>

#include <opencv2/core.hpp>

namespace rolamos {

// `src` CV_8UC4 or CV_16UC4; `src_to_dst` maps src pixels to dst pixels (as warpPerspective's M
// without WARP_INVERSE_MAP). Returns a `size` image of src's type.
cv::Mat WarpBilinear(const cv::Mat& src, const cv::Matx33d& src_to_dst, cv::Size size);

// The same warp blended straight into a canvas, with no warped image in between (the patch
// writer's full-resolution bands): for each pixel of `sum` (CV_32FC3) and `weight_sum` (CV_32F,
// the same size) that the frame reaches, code = the interpolated fourth channel rounded, adds
// weight[code] x (B, G, R) x `unit` to the sum and weight[code] to the weight; code 0 (the
// frame's outer ring and beyond) adds nothing. The colour is not rounded first. One thread:
// the caller splits the canvas.
void WarpAccumulate(const cv::Mat& src, const cv::Matx33d& src_to_dst, const std::array<float, 256>& weight,
                    float unit, cv::Mat& sum, cv::Mat& weight_sum);

}  // namespace rolamos
