// Stage 1's spatial filter: cv::bilateralFilter, the same weights, computed faster for 8-bit
// colour frames where the CPU has AVX-512. OpenCV 4.6 reads each neighbour's colour weight from
// a table of 768 floats with a vector gather: 10 ms a 1292 x 964 keyframe on one core, a tenth
// of a still's CPU besides SIFT. With the engine's sigma (12 grey levels), every colour weight
// past a difference of 62 is below 1e-6 of the centre's: the table's first 64 entries fit in
// four registers and are read by permutes, 3 ms. With AVX-512 BW, 32 pixels at a time: the
// colour differences in 16 bits and each neighbour's colour x space weights read from a table
// of their own, a quarter less. The weights left out move a value by under
// 0.01 grey levels: it differs from OpenCV's only where that tips a rounding, by one grey level
// (none on the benchmark frames tried at 1292 x 964 and 800 x 600; 1 of 700,000 in the test).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// As cv::bilateralFilter(src, dst, diameter, sigma_color, sigma_space) (borders reflected,
// BORDER_REFLECT_101). The fast path: CV_8UC3, sigma_color up to kFastBilateralMaxSigmaColor,
// an AVX-512 CPU; anything else is OpenCV's own.
void BilateralFilter(const cv::Mat& src, cv::Mat& dst, int diameter, double sigma_color, double sigma_space);

// The colour sigma (grey levels) up to which the colour weights beyond the 64-entry table are
// below 3e-6 of the centre's.
inline constexpr double kFastBilateralMaxSigmaColor = 12.5;

// Whether BilateralFilter takes the fast path for `src` on this CPU.
bool FastBilateralApplies(const cv::Mat& src, double sigma_color);

}  // namespace rolamos
