// Our own bilinear perspective warps, where OpenCV's cost the engine most (the temporal filter's
// is at the end). The patch writer's: a frame with its feather code interleaved (BGRW, 8 or 16
// bits) blended into a full-resolution canvas, bilinear, edge pixels repeated: the interpolation
// of cv::warpPerspective(src, dst, M, size, INTER_LINEAR, BORDER_REPLICATE) without the warped
// image in between. OpenCV 4.6 warps a 16-bit 1292 x 964 frame onto 1500 x 1300 pixels in 22 ms
// on one thread (it finds each pixel's source in double and rounds it to 1/32 px, and its
// 16-bit remap is scalar); here sources are found eight at a time and each pixel is one vector
// interpolation (AVX2 where the CPU has it): 11 ms for the same warp written out as an image,
// less added straight into the sums. Sources are rounded to 1/256 px, so values differ from
// OpenCV's by what the image changes over 1/64 px.
#pragma once

#include <array>

#include <opencv2/core.hpp>

namespace rolamos {

// `src` CV_8UC4 or CV_16UC4; `src_to_dst` maps src pixels to the canvas's pixels (as
// warpPerspective's M without WARP_INVERSE_MAP). For each pixel of `sum` (CV_32FC3) and
// `weight_sum` (CV_32F, the same size) that the frame reaches, with code = the interpolated
// fourth channel rounded: adds weight[code] x (B, G, R) x `unit` to the sum and weight[code] to
// the weight; code 0 (the frame's outer ring and beyond) adds nothing. The colour is not
// rounded first. One thread: the caller splits the canvas.
// `zero`: the edges of `src` whose code is 0 all along (ZeroCodeEdges: a whole frame's feather
// code, or a part of a frame where it meets the frame's edge). The pixels whose source lies
// beyond such an edge take their taps from it and add nothing: they are not computed (a turned
// frame's bounding box is up to half as large again as the frame). Every other pixel is.
struct CodeEdges {
  bool left = false, right = false, top = false, bottom = false;
};
void WarpAccumulate(const cv::Mat& src, const cv::Matx33d& src_to_dst, const std::array<float, 256>& weight,
                    float unit, cv::Mat& sum, cv::Mat& weight_sum, const CodeEdges& zero);
// The edges (first and last column, first and last row) along which the fourth channel of
// `bgrw` (CV_8UC4 or CV_16UC4) is 0.
CodeEdges ZeroCodeEdges(const cv::Mat& bgrw);

// The temporal filter's warp: each pixel of `dst` (CV_8UC3) whose source position, through
// `dst_to_src`, has its four bilinear taps inside `src` (CV_8UC3) gets the interpolated colour;
// the others keep theirs: cv::warpPerspective(src, dst, dst_to_src, dst.size(), INTER_LINEAR |
// WARP_INVERSE_MAP, BORDER_TRANSPARENT). OpenCV's takes 5 ms a 1292 x 964 frame on one core;
// with AVX-512, sixteen pixels at a time (positions in float, taps gathered): 3 ms. Values differ
// from OpenCV's by its positions' rounding to 1/32 px (a grey level or two on sharp edges), and
// the pixels at the footprint's very edge may be taken or left the other way. Without AVX-512,
// OpenCV's own.
void WarpInside(const cv::Mat& src, const cv::Matx33d& dst_to_src, cv::Mat& dst);

}  // namespace rolamos
