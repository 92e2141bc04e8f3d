// Stage 2's keypoints: SIFT (Lowe 2004, sections 3-5) as OpenCV 4.6's cv::SIFT finds and
// describes them, on one scale space for both.
//
// cv::SIFT::detectAndCompute builds its pyramid once, but describes slowly (see
// sift_descriptor.h); detecting with OpenCV and describing here built the pyramid twice and
// gained nothing. So the search is here too, on our own pyramid (sift_pyramid.h, the same
// images): the difference-of-Gaussian extrema against their 26 neighbours sixteen pixels at a
// time, each refined to sub-pixel and sub-scale (section 4); then only the strongest oriented
// (section 5: OpenCV orients every extremum above the threshold and then keeps the strongest
// `features`, which cost as much as the search), then OpenCV's own mask filter.
//
// The keypoints are OpenCV's up to float rounding: its build contracts its arithmetic into fused
// multiply-adds its own way, so the last bit of a position, response or angle may differ, and
// so, rarely, may a candidate on the edge of a threshold. On the tests' seafloors every keypoint
// is OpenCV's; on the 33 survey kinds of bench/run_engine_spread.py 30 place every frame exactly
// as OpenCV's SIFT did, the other three within a pixel (session 31).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct SiftOptions {
  int features = 1000;              // the strongest kept (0 = all)
  int layers = 3;                   // layers per octave
  double contrast_threshold = 0.04;  // of the DoG extrema, after refinement (divided among the layers)
  double edge_threshold = 10;       // the ratio of principal curvatures above which an extremum is an edge
  double sigma = 1.6;               // the base blur of each octave; the first octave is at twice the
                                    // image's size (octave -1), as OpenCV 4.6 always searches

  bool IsValid(std::string* error) const;
};

// Keypoints of `image` (CV_8UC1) outside `mask` (CV_8UC1, 0 = left out; empty = none), with their
// descriptors (CV_32F, 128 per keypoint, in order), as cv::SIFT::create(features, layers,
// contrast_threshold, edge_threshold, sigma)->detectAndCompute(image, mask, ...) gives them.
// `descriptors` null: the keypoints alone, as cv::SIFT's detect gives them.
std::vector<cv::KeyPoint> FindSift(const cv::Mat& image, const cv::Mat& mask, const SiftOptions& options,
                                   cv::Mat* descriptors);

}  // namespace rolamos
