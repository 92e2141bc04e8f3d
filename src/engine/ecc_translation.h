// The enhanced correlation coefficient (Evangelidis and Psarakis, "Parametric image alignment
// using enhanced correlation coefficient maximization", PAMI 2008) for a translation: the ECC
// refinement of the paper's section on sub-pixel registration, as the engine runs it.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace rolamos {

struct EccTranslation {
  bool ok = false;
  double correlation = 0;  // the last iteration's, before its step (as OpenCV returns it)
  cv::Point2d shift;       // template pixel (x, y) is input pixel (x, y) + shift
  int iterations = 0;
  std::string failure;     // why not ok
};

// What cv::findTransformECC(templ, input, W, MOTION_TRANSLATION, {COUNT + EPS, iterations,
// epsilon}, input_mask, 3) computes from W = [1 0 start.x; 0 1 start.y]: both images smoothed
// 3 x 3, the input's gradients and its mask (non-zero = valid, eroded by the smoothing), steps
// until the correlation changes by less than `epsilon`. OpenCV warps three images and a mask per
// step and makes a dozen more passes over them; a translation's bilinear weights are the same at
// every pixel, so here each step is one pass of sixteen pixels at a time (AVX-512; one at a time
// elsewhere), its sums in double, sampling where OpenCV samples (positions rounded to 1/32 pixel).
// `templ` and `input`: CV_32F of one size; `input_mask`: CV_8U of that size, or empty. Fails
// (ok = false) where OpenCV throws: the correlation is not a number, or the step would lower it;
// and where the shift leaves the images by more than 16 pixels.
EccTranslation FindEccTranslation(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask,
                                  cv::Point2d start, int iterations, double epsilon);

namespace internal {
// The same, one pixel at a time (CPUs without AVX-512).
EccTranslation FindEccTranslationScalar(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask,
                                        cv::Point2d start, int iterations, double epsilon);
}  // namespace internal

}  // namespace rolamos
