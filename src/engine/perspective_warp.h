// cv::warpPerspective's bilinear warp of 8-bit images, to OpenCV's pixels, faster. The engine
// warps with OpenCV where its placements were measured with OpenCV's pixels: a frame turned
// past the tracker's turn limit is followed in the next frame warped back onto it, and every
// keyframe goes into the working canvas warped, and ECC sees the canvas from each keyframe
// warped. On a random walk those warps were 8 % of all the CPU, most of it on the thread that
// follows frames (bench/RESULTS.md, session 34).
//
// OpenCV 4.6 finds each destination pixel's source in double, 64 pixels of a row at a time from
// the block's first (its order of operations decides the last bit), rounds it to 1/32 pixel, and
// then interpolates with 15-bit weights in a second pass. Here the same arithmetic, eight sources
// at a time with AVX-512, and the taps gathered and weighted in the same pass: the same pixels
// (perspective_warp_test.cc). Without AVX-512, and for what is not handled here, OpenCV's own.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// cv::warpPerspective(src, dst, M, size, flags, border) where `flags` is INTER_LINEAR, with
// WARP_INVERSE_MAP or not: 8-bit grey or BGRW (CV_8UC1, CV_8UC4) with `border` BORDER_REPLICATE,
// BORDER_REFLECT or BORDER_REFLECT_101, and float grey or colour (CV_32FC1, CV_32FC3: ECC's view
// of the working canvas's sums) with BORDER_CONSTANT (zeros, OpenCV's default value). Others go
// to OpenCV.
void WarpPerspectiveLinear(const cv::Mat& src, cv::Mat& dst, const cv::Matx33d& M, cv::Size size, int flags,
                           int border);

}  // namespace rolamos
