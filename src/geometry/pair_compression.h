// Matched pairs between two frames as the homography they fit, held at a few weighted points.
//
// A bundle adjustment holds a row pair per matched pair; tens of thousands of edges of 48 pairs
// each are most of `rolamos align`'s memory at 10,000 frames. The pairs' noise carries nothing
// the least-squares homography does not, so the pairs are replaced by that homography sampled at
// the centres of the occupied cells of a grid over them, each weighing as the pairs of its cell
// (weight^2 = their count: the same pull in a least-squares solve), stretched about the mean so
// that the points' second moments are the pairs' (cell centres alone lose the spread within
// cells, and with it some of the pairs' hold on rotation and scale).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct CompressedPairs {
  std::vector<cv::Point2f> in_a, in_b;
  std::vector<float> weight;  // per point; weight^2 = the pairs it stands for
  double scatter_px = 0;      // the pairs' RMS distance from the fitted homography, pixels of b
  int pairs = 0;              // the pairs compressed
};

// At most `points` points (a grid of floor(sqrt(points)) cells a side). False, and `out`
// untouched, when there is nothing to gain or too little to hold a homography: fewer than 8
// pairs or no more than the points, fewer than 5 occupied cells, or no fit. The homography is
// fitted by least squares, or with `loss_px` > 0 under a Cauchy loss from that many pixels
// (iteratively reweighted): a few pairs off by pixels, a corner followed onto its neighbour, do
// not bend it; the scatter still counts every pair.
bool CompressPairs(const std::vector<cv::Point2f>& in_a, const std::vector<cv::Point2f>& in_b, int points,
                   CompressedPairs* out, double loss_px = 0);

}  // namespace rolamos
