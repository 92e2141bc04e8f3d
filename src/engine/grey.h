// A colour frame in grey, as cv::cvtColor(COLOR_BGR2GRAY) makes it: 0.299 R + 0.587 G + 0.114 B
// in OpenCV 4's 15-bit fixed point (9798, 19235, 3735), rounded. The engine takes every frame to
// grey three times (to follow it, to describe it, to refine it against the patch), 1.6 % of a
// 1292 x 964 still's CPU through OpenCV's call; here sixty-four pixels at a time with AVX-512:
// the same bytes (grey_test.cc).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// `bgr` CV_8UC3 into `grey` (CV_8UC1, its size); anything else, and CPUs without AVX-512, go to
// cv::cvtColor (BGR2GRAY or BGRA2GRAY by the channels, a copy of a grey image).
void BgrToGrey(const cv::Mat& bgr, cv::Mat& grey);

}  // namespace rolamos
