// SIFT's scale space (Lowe 2004, section 3) as OpenCV 4.6 builds it, the same images to the bit:
// OpenCV's kernels and borders, and its blur's order of operations (rows then columns, fused
// multiply-adds from the first tap; the column pass folds each pair of rows about the centre),
// sixteen pixels at a time on AVX-512 and on every core, twice OpenCV's speed; elsewhere
// cv::GaussianBlur itself. Shared by the keypoint search and the descriptors.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// SIFT's first image: `gray` (CV_8UC1) as float, doubled with INTER_LINEAR when `doubled` (the
// first octave, -1), blurred up to `sigma` from the 0.5 the input is assumed to have.
cv::Mat SiftBaseImage(const cv::Mat& gray, bool doubled, float sigma);

// cv::resize(f, dst, 2 x f's size, 0, 0, INTER_LINEAR)'s pixels for a float image: the doubled
// first octave's image, rows doubled across into a ring of three and then down, sixteen pixels at
// a time (OpenCV's generic resize with its tables: 0.9 % of a still's CPU).
cv::Mat DoubleLinear(const cv::Mat& f);

// OpenCV's Gaussian pyramid from `base`: octave by octave, each layer blurred from the one before,
// the next octave's base layer `layers` of this one halved (nearest neighbour). pyramid[o][i] up
// to layer `top` of the last octave (every octave before it to at least layer `layers`). With
// `dog`, also the differences of Gaussians, (*dog)[o][i] = pyramid[o][i + 1] - pyramid[o][i]
// (cv::subtract's values), made while each layer is blurred.
std::vector<std::vector<cv::Mat>> SiftGaussianPyramid(const cv::Mat& base, int octaves, int layers, int top,
                                                      double sigma, std::vector<std::vector<cv::Mat>>* dog = nullptr);

// Whether SIFT's own paths (this pyramid's blur, FindSift, DescribeSift) run on this CPU: they need
// AVX-512 and FMA; elsewhere each is OpenCV's.
bool FastSiftApplies();

// OpenCV's octave and layer packed in a keypoint, and the scale from the octave's pixels to the
// image's.
void UnpackSiftOctave(const cv::KeyPoint& k, int* octave, int* layer, float* scale);

}  // namespace rolamos
