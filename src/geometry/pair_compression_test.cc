#include "geometry/pair_compression.h"

#include <gtest/gtest.h>

#include "util/homography.h"

namespace rolamos {
namespace {

// Pairs clustered unevenly over part of a frame (three blobs), under a homography with 0.5 px of
// noise on b.
struct Blobs {
  std::vector<cv::Point2f> in_a, in_b;
  cv::Matx33d H{1.02, 0.03, 80, -0.02, 0.99, 15, 2e-5, 1e-5, 1};
  Blobs() {
    cv::RNG rng(3);
    const cv::Point2f centres[] = {{60, 50}, {300, 80}, {180, 260}};
    const int sizes[] = {120, 40, 15};
    for (int b = 0; b < 3; ++b)
      for (int i = 0; i < sizes[b]; ++i) {
        const cv::Point2f p = centres[b] + cv::Point2f(float(rng.gaussian(25)), float(rng.gaussian(25)));
        const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
        in_a.push_back(p);
        in_b.emplace_back(float(q[0] / q[2] + rng.gaussian(0.5)), float(q[1] / q[2] + rng.gaussian(0.5)));
      }
  }
};

// The points stand for every pair (weights^2 add up to them), with the pairs' mean and second
// moments: in a least-squares solve they pull as the pairs do.
TEST(PairCompression, PointsCarryThePairsCountMeanAndSpread) {
  const Blobs b;
  CompressedPairs c;
  ASSERT_TRUE(CompressPairs(b.in_a, b.in_b, 9, &c));
  EXPECT_LE(c.in_a.size(), 9u);
  EXPECT_EQ(c.pairs, int(b.in_a.size()));
  double count = 0;
  cv::Point2d mean, pairs_mean;
  for (size_t k = 0; k < c.in_a.size(); ++k) {
    count += double(c.weight[k]) * c.weight[k];
    mean += double(c.weight[k]) * c.weight[k] * cv::Point2d(c.in_a[k]);
  }
  EXPECT_NEAR(count, double(b.in_a.size()), 1e-3);
  mean *= 1.0 / count;
  for (const auto& p : b.in_a) pairs_mean += cv::Point2d(p);
  pairs_mean *= 1.0 / double(b.in_a.size());
  EXPECT_LT(cv::norm(mean - pairs_mean), 0.01);
  cv::Point2d spread, pairs_spread;
  for (size_t k = 0; k < c.in_a.size(); ++k) {
    const cv::Point2d d = cv::Point2d(c.in_a[k]) - mean;
    spread += double(c.weight[k]) * c.weight[k] * cv::Point2d(d.x * d.x, d.y * d.y);
  }
  for (const auto& p : b.in_a) {
    const cv::Point2d d = cv::Point2d(p) - pairs_mean;
    pairs_spread += cv::Point2d(d.x * d.x, d.y * d.y);
  }
  EXPECT_NEAR(spread.x / pairs_spread.x, 1.0, 0.01);
  EXPECT_NEAR(spread.y / pairs_spread.y, 1.0, 0.01);
  // On the fitted homography, which is close to the true one; the scatter is the noise's.
  for (size_t k = 0; k < c.in_a.size(); ++k) {
    const cv::Vec3d q = b.H * cv::Vec3d(c.in_a[k].x, c.in_a[k].y, 1);
    EXPECT_LT(cv::norm(cv::Point2d(q[0] / q[2], q[1] / q[2]) - cv::Point2d(c.in_b[k])), 0.5);
  }
  EXPECT_NEAR(c.scatter_px, 0.5 * std::sqrt(2.0), 0.15);
}

TEST(PairCompression, NothingToGainLeavesThePairs) {
  const Blobs b;
  CompressedPairs c;
  c.pairs = -1;
  EXPECT_FALSE(CompressPairs(b.in_a, b.in_b, 0, &c));  // not asked for
  EXPECT_FALSE(CompressPairs(b.in_a, b.in_b, 4, &c));  // a 2 x 2 grid cannot hold a homography
  const std::vector<cv::Point2f> few_a(b.in_a.begin(), b.in_a.begin() + 9), few_b(b.in_b.begin(), b.in_b.begin() + 9);
  EXPECT_FALSE(CompressPairs(few_a, few_b, 9, &c));     // no more pairs than points
  const std::vector<cv::Point2f> one_a(8, cv::Point2f(5, 5)), one_b(8, cv::Point2f(7, 5));
  EXPECT_FALSE(CompressPairs(one_a, one_b, 9, &c));     // one spot: no homography
  EXPECT_EQ(c.pairs, -1);
}

// Pairs followed to a tenth of a pixel, one in ten of them onto a neighbour 4 px off: fitted under
// a Cauchy loss from half a pixel, the points lie on the true homography; by least squares the
// outliers bend it. The scatter counts every pair either way.
TEST(PairCompression, ACauchyFitIsNotBentByAFewPairsFarOff) {
  const cv::Matx33d H(1.01, 0.02, 60, -0.015, 0.995, 20, 1e-5, -2e-5, 1);
  std::vector<cv::Point2f> a, b;
  cv::RNG rng(9);
  for (int y = 10; y < 300; y += 15)
    for (int x = 10; x < 400; x += 15) {
      const cv::Point2d q = ApplyHomography(H, cv::Point2f(float(x), float(y)));
      const bool off = rng.uniform(0, 10) == 0;
      a.emplace_back(float(x), float(y));
      b.emplace_back(float(q.x + rng.gaussian(0.1) + (off ? 4.0 : 0.0)), float(q.y + rng.gaussian(0.1) + (off ? -3.0 : 0.0)));
    }
  const auto worst = [&](const CompressedPairs& c) {
    double w = 0;
    for (size_t k = 0; k < c.in_a.size(); ++k) w = std::max(w, cv::norm(ApplyHomography(H, c.in_a[k]) - cv::Point2d(c.in_b[k])));
    return w;
  };
  CompressedPairs robust, squares;
  ASSERT_TRUE(CompressPairs(a, b, 9, &robust, 0.5));
  ASSERT_TRUE(CompressPairs(a, b, 9, &squares));
  EXPECT_LT(worst(robust), 0.08);
  EXPECT_GT(worst(squares), 0.15);
  EXPECT_GT(robust.scatter_px, 1.0);  // the outliers still count in the edge's scatter
  EXPECT_EQ(robust.pairs, int(a.size()));
}

}  // namespace
}  // namespace rolamos
