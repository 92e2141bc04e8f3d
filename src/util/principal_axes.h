// Principal component analysis of a sample's rows by a randomised subspace iteration (Halko,
// Martinsson and Tropp 2011, algorithm 4.4). cv::PCA solves the sample's whole eigenproblem by
// Jacobi rotations: for align's retrieval (3,000 VLAD vectors of 4,096 values, 128 axes kept)
// that took 22 s of one core, a sixth of a 10,000-frame align. The iteration finds the same
// subspace from a few products with the sample, on every core, in about a second.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

struct PrincipalAxes {
  cv::Mat mean;  // 1 x d, CV_32F
  cv::Mat axes;  // k x d, CV_32F: orthonormal rows, the direction of most variance first
  // (rows - mean) x axes^T: each row's coordinates along the axes (n x k, CV_32F).
  cv::Mat Project(const cv::Mat& rows) const;
};

// The mean of `rows` (n x d, CV_32F) and its `dims` principal axes (at most min(n, d)). Problems
// of rank up to 1,024, or where the axes kept are most of the rank, are solved exactly
// (cv::PCA); the others by `iterations` rounds of the subspace iteration from a seeded random
// start, so the result is the same every run.
PrincipalAxes FindPrincipalAxes(const cv::Mat& rows, int dims, int iterations = 5);

}  // namespace rolamos
