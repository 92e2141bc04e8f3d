// A frame shrunk by a factor that is not a whole number, averaging the source pixels each
// destination pixel covers: cv::resize's INTER_AREA, the detection image SIFT runs on (0.36 of a
// 1292 x 964 frame, 0.58 of 800 x 600). OpenCV 4.6 computes it one table entry at a time, 2.7 ms
// a 1292 x 964 frame and 2.1 ms an 800 x 600 one on one core, 4 % of a still's CPU; here sixteen
// destination pixels at a time where the CPU has AVX-512, with OpenCV's tables and its order of
// multiplications and additions: the same pixels (tests).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// cv::resize(src, dst, cv::Size(), scale, scale, cv::INTER_AREA) for `src` 8-bit (1 to 4
// channels) and 0 < scale < 1. Scales whose inverse is a whole number of 3 or more take OpenCV's
// block average, here a column's sums over a block's rows first (OpenCV 4.6 adds each value
// through a table of offsets, one at a time: 1.5 % of a 1292 x 964 still's CPU went into the
// exposure gains' eighth-size copies). Other depths, halving, and other scales on CPUs without
// AVX-512 go to cv::resize itself.
void ResizeArea(const cv::Mat& src, cv::Mat& dst, double scale);
// cv::resize(src, dst, dsize, 0, 0, cv::INTER_AREA): the block average where the sizes' ratio is
// a whole number of 3 or more each way, cv::resize otherwise.
void ResizeArea(const cv::Mat& src, cv::Mat& dst, cv::Size dsize);

}  // namespace rolamos
