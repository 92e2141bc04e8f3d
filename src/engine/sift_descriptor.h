// Stage 2's descriptors: SIFT's 128-value descriptors of keypoints OpenCV's SIFT found, computed
// as OpenCV 4.6 computes them (Lowe 2004, section 6: a 4 x 4 grid of 8-bin orientation
// histograms over the keypoint's Gaussian-blurred octave image, trilinear, Gaussian-weighted,
// clipped at 0.2 and scaled to 0..255), faster where the CPU has AVX-512.
//
// At the engine's detection size (about 0.16 million pixels, first octave doubled), describing a
// keyframe's 1,000 keypoints was a fifth of a still's CPU: OpenCV builds each keypoint's window
// of samples one pixel at a time, then runs three passes over it (atan2, magnitude, exp) and
// scatters each sample into eight histogram bins one float at a time. Here sixteen samples at a
// time in one pass (OpenCV's atan2 polynomial and trilinear split, the same operations), the
// Gaussian weight as a row's factor times a column's, each cell's two bins added as one pair,
// the keypoints taken in the order of their rows so that windows overlap in cache: 2.7 times
// OpenCV's speed on one core (bench/RESULTS.md, session 31).
//
// Values are OpenCV's up to float rounding (the weight's exp is not OpenCV's): an entry rounds
// the other way where it was within a hair of a half. On the tests' seafloors no more than one
// entry of a descriptor, and fewer than 1 in 10,000 entries, differ, by one.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// Descriptors (CV_32F, one row of 128 per keypoint, in order) of `keypoints` found by
// cv::SIFT on `image` (CV_8UC1) with `layers` layers per octave and base sigma `sigma`: their
// `octave` packed as OpenCV packs it (octave -1: the doubled first octave), their positions in
// `image`'s pixels. As cv::SIFT::compute(image, keypoints, descriptors) would give, which it is
// where FastSiftApplies (sift_pyramid.h) is false.
void DescribeSift(const cv::Mat& image, const std::vector<cv::KeyPoint>& keypoints, int layers, double sigma,
                  cv::Mat* descriptors);

// The same on a Gaussian pyramid already built (SiftGaussianPyramid; pyramid[0] is octave
// `first_octave`), where FastSiftApplies (sift_pyramid.h).
void DescribeSiftOn(const std::vector<std::vector<cv::Mat>>& pyramid, int first_octave,
                    const std::vector<cv::KeyPoint>& keypoints, cv::Mat* descriptors);

}  // namespace rolamos
