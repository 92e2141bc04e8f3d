#include "engine/lucas_kanade.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace rolamos {
namespace {

// Textured ground and the same ground seen through a small rotation and shift.
struct Pair {
  cv::Mat a, b;
  cv::Matx33d a_to_b;
};

Pair MakePair(int width, int height) {
  cv::RNG rng(7);
  cv::Mat noise(height, width, CV_32F);
  rng.fill(noise, cv::RNG::NORMAL, 0, 1);
  cv::Mat fine, coarse;
  cv::GaussianBlur(noise, fine, cv::Size(), 1.2);
  cv::GaussianBlur(noise, coarse, cv::Size(), 6.0);
  cv::Mat ground = 90 + 600 * fine + 3000 * coarse;
  Pair p;
  ground.convertTo(p.a, CV_8U);
  const double angle = 1.5 * CV_PI / 180, c = std::cos(angle), s = std::sin(angle);
  p.a_to_b = cv::Matx33d(c, -s, 6.3, s, c, -4.7, 0, 0, 1);
  cv::warpPerspective(p.a, p.b, cv::Mat(p.a_to_b), p.a.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  return p;
}

cv::Point2f Apply(const cv::Matx33d& H, cv::Point2f p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
  return {float(q[0] / q[2]), float(q[1] / q[2])};
}

struct Tracks {
  std::vector<cv::Point2f> to;
  std::vector<uchar> ok;
};

class LucasKanadeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    pair_ = MakePair(640, 480);
    cv::buildOpticalFlowPyramid(pair_.a, from_, win_, levels_, true);
    cv::buildOpticalFlowPyramid(pair_.b, to_, win_, levels_, true);
    cv::goodFeaturesToTrack(pair_.a, points_, 300, 0.01, 10);
    // Points at and past the edges too: the kernel reads those windows another way, and OpenCV
    // gives up on some of them.
    for (float y : {2.f, 240.f, 477.f})
      for (float x : {0.5f, 3.f, 620.f, 630.f, 636.f, 639.f}) points_.push_back({x, y});
    points_.push_back({-30.f, 100.f});
    points_.push_back({700.f, 100.f});
    // Started 2-3 pixels from where the points truly are, as a motion model would.
    for (const auto& p : points_) guess_.push_back(Apply(pair_.a_to_b, p) + cv::Point2f(2.2f, -1.6f));
  }

  Tracks OpenCv() const {
    Tracks r{guess_, {}};
    cv::calcOpticalFlowPyrLK(from_, to_, points_, r.to, r.ok, cv::noArray(), win_, levels_, until_,
                             cv::OPTFLOW_USE_INITIAL_FLOW, 1e-4);
    return r;
  }
  Tracks Ours() const {
    Tracks r{guess_, {}};
    FollowLucasKanade(from_, to_, points_, &r.to, &r.ok, win_, levels_, until_, 1e-4);
    return r;
  }
  Tracks Scalar() const {
    Tracks r{guess_, {}};
    detail::FollowLucasKanadeScalar(from_, to_, points_, &r.to, &r.ok, win_, levels_, until_, 1e-4);
    return r;
  }

  Pair pair_;
  std::vector<cv::Mat> from_, to_;
  std::vector<cv::Point2f> points_, guess_;
  const cv::Size win_{21, 21};
  const int levels_ = 3;
  const cv::TermCriteria until_{cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 10, 0.03};
};

// How many points two runs agree on (status, and place within `px` where both followed).
int Agreeing(const Tracks& x, const Tracks& y, double px) {
  int n = 0;
  for (size_t i = 0; i < x.to.size(); ++i)
    n += x.ok[i] == y.ok[i] && (!x.ok[i] || cv::norm(x.to[i] - y.to[i]) <= px);
  return n;
}

TEST_F(LucasKanadeTest, FollowsAsOpenCvDoes) {
  const Tracks cv = OpenCv(), ours = Ours();
  const int n = int(points_.size());
  ASSERT_GT(n, 250);
  // Sums added in another order round differently: a point may end a thousandth of a pixel away.
  EXPECT_GE(Agreeing(cv, ours, 1e-3), n - 3);
  EXPECT_GE(Agreeing(cv, ours, 0.05), n - 1);
  // The points off the image are lost by both.
  EXPECT_FALSE(ours.ok[size_t(n - 2)]);
  EXPECT_FALSE(ours.ok[size_t(n - 1)]);
}

TEST_F(LucasKanadeTest, VectorRowsComputeWhatScalarRowsDo) {
  if (!LucasKanadeVectorised()) GTEST_SKIP() << "no AVX2 on this CPU: OpenCV's kernel runs";
  const Tracks scalar = Scalar(), ours = Ours();
  EXPECT_GE(Agreeing(scalar, ours, 1e-3), int(points_.size()) - 1);
}

// The median distance of the followed points from where they truly are.
double MedianError(const Tracks& t, const std::vector<cv::Point2f>& points, const cv::Matx33d& truth) {
  std::vector<double> error;
  for (size_t i = 0; i < points.size(); ++i)
    if (t.ok[i]) error.push_back(cv::norm(t.to[i] - Apply(truth, points[i])));
  if (error.size() < 250) return 1e9;
  std::nth_element(error.begin(), error.begin() + long(error.size() / 2), error.end());
  return error[error.size() / 2];
}

TEST_F(LucasKanadeTest, PlacesPointsWhereTheyAreAsWellAsOpenCv) {
  const double ours = MedianError(Ours(), points_, pair_.a_to_b);
  const double opencv = MedianError(OpenCv(), points_, pair_.a_to_b);
  // Lucas-Kanade's translation-only window against a 1.5-degree turn, stopped at 0.03-pixel steps.
  EXPECT_LT(ours, 0.1);
  EXPECT_NEAR(ours, opencv, 0.002);
}

TEST_F(LucasKanadeTest, PreparedWindowsFollowAsFreshOnes) {
  const auto windows = PrepareLucasKanade(from_, points_, win_, levels_, 1e-4);
  const Tracks fresh = Ours();
  // Read twice, as frames after a keyframe read them: the same each time, and as made afresh.
  for (int k = 0; k < 2; ++k) {
    Tracks again{guess_, {}};
    FollowLucasKanade(*windows, from_, to_, points_, &again.to, &again.ok, until_);
    EXPECT_EQ(again.ok, fresh.ok);
    EXPECT_EQ(Agreeing(again, fresh, 0.0), int(points_.size()));
  }
}

TEST_F(LucasKanadeTest, APyramidWithoutBordersGoesToOpenCv) {
  // Levels cut out of plain images have no border to read past the edge: OpenCV's own kernel
  // takes them (and asks for what it needs).
  std::vector<cv::Mat> bare_from, bare_to;
  for (const auto& m : from_) bare_from.push_back(m.clone());
  for (const auto& m : to_) bare_to.push_back(m.clone());
  Tracks r{guess_, {}};
  EXPECT_ANY_THROW(FollowLucasKanade(bare_from, bare_to, points_, &r.to, &r.ok, win_, levels_, until_, 1e-4));
}

}  // namespace
}  // namespace rolamos
