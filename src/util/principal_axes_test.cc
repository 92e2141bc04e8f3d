#include "util/principal_axes.h"

#include <cmath>

#include <gtest/gtest.h>

#include "rolamos/error.hpp"

namespace rolamos {
namespace {

// n rows of d values: a mean, then `d` directions (the axes turned by four random reflections)
// with spreads falling by a tenth each, plus a little spread in every direction.
cv::Mat Sample(int n, int d, int seed) {
  cv::RNG rng(seed);
  cv::Mat rows(n, d, CV_32F);
  rng.fill(rows, cv::RNG::NORMAL, 0, 1);
  for (int j = 0; j < d; ++j) rows.col(j) *= std::pow(0.9, j) + 0.01;
  for (int k = 0; k < 4; ++k) {  // x - 2 (x . v) v
    cv::Mat v(d, 1, CV_32F);
    rng.fill(v, cv::RNG::NORMAL, 0, 1);
    v /= cv::norm(v);
    rows -= 2 * (rows * v) * v.t();
  }
  cv::Mat mean(1, d, CV_32F);
  rng.fill(mean, cv::RNG::UNIFORM, -3, 3);
  for (int r = 0; r < n; ++r) rows.row(r) += mean;
  return rows;
}

// The iterated subspace is cv::PCA's: every exact axis but the last few (whose variances are
// within a tenth of those left out) lies in it, the axes come in the same order, orthonormal.
TEST(PrincipalAxes, FindsTheSubspaceTheExactAnalysisFinds) {
  const cv::Mat rows = Sample(1500, 1100, 7);
  const int dims = 30;
  const PrincipalAxes fast = FindPrincipalAxes(rows, dims);
  const cv::PCA exact(rows, cv::Mat(), cv::PCA::DATA_AS_ROW, dims);
  ASSERT_EQ(fast.axes.rows, dims);
  ASSERT_EQ(fast.axes.cols, 1100);
  EXPECT_LT(cv::norm(fast.mean, exact.mean, cv::NORM_INF), 1e-4);
  const cv::Mat gram = fast.axes * fast.axes.t();
  EXPECT_LT(cv::norm(gram, cv::Mat::eye(dims, dims, CV_32F), cv::NORM_INF), 1e-4);
  for (int k = 0; k < dims - 5; ++k) {
    const cv::Mat along = fast.axes * exact.eigenvectors.row(k).t();  // its coordinates in ours
    EXPECT_GT(cv::norm(along), 0.999) << "axis " << k;
    EXPECT_GT(std::abs(along.at<float>(k)), 0.99) << "axis " << k << " out of order";
  }
}

TEST(PrincipalAxes, ProjectsCentredRows) {
  const cv::Mat rows = Sample(1200, 1100, 3);
  const PrincipalAxes p = FindPrincipalAxes(rows, 12);
  const cv::Mat got = p.Project(rows.rowRange(0, 5));
  for (int r = 0; r < 5; ++r) {
    const cv::Mat expected = (rows.row(r) - p.mean) * p.axes.t();
    EXPECT_LT(cv::norm(got.row(r), expected, cv::NORM_INF), 1e-3) << "row " << r;
  }
}

// Small problems are solved exactly: the same axes as cv::PCA, up to sign.
TEST(PrincipalAxes, SolvesSmallProblemsExactly) {
  const cv::Mat rows = Sample(40, 30, 5);
  const PrincipalAxes p = FindPrincipalAxes(rows, 10);
  const cv::PCA exact(rows, cv::Mat(), cv::PCA::DATA_AS_ROW, 10);
  for (int k = 0; k < 10; ++k)
    EXPECT_NEAR(std::abs(p.axes.row(k).dot(exact.eigenvectors.row(k))), 1.0, 1e-5) << "axis " << k;
}

TEST(PrincipalAxes, RefusesMoreAxesThanTheSampleHolds) {
  const cv::Mat rows = Sample(20, 10, 1);
  EXPECT_THROW(FindPrincipalAxes(rows, 11), Error);
  EXPECT_THROW(FindPrincipalAxes(rows, 0), Error);
  EXPECT_THROW(FindPrincipalAxes(cv::Mat(1, 10, CV_32F, cv::Scalar(1)), 1), Error);
}

}  // namespace
}  // namespace rolamos
