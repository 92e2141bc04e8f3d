// Moving 8-bit channels between interleaved and planar layouts, where OpenCV's calls cost more
// than the moves: cv::split ran row by row into the bilateral filter's padded planes (a trace
// region and a dispatch each row: 1 % of a 1292 x 964 still's CPU), and cv::mixChannels put the
// feather code beside each frame's colour (0.7 %). With AVX-512 VBMI, 64 pixels at a time by
// byte permutes; the same bytes (channel_shuffle_test.cc). Elsewhere OpenCV's calls.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// The three channels of `bgr` (CV_8UC3) into planes[0..2] (CV_8UC1, its size; views into larger
// images are kept, as cv::split keeps them).
void SplitBgr(const cv::Mat& bgr, cv::Mat planes[3]);

// `bgr` (CV_8UC3) with `fourth` (CV_8UC1, its size) as the fourth channel: CV_8UC4.
cv::Mat InterleaveBgrAnd(const cv::Mat& bgr, const cv::Mat& fourth);

}  // namespace rolamos
