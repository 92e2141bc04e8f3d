#include "geometry/plane_adjustment.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

#include "geometry/plane_camera.h"

namespace rolamos {
namespace {

const cv::Size kFrame(400, 300);
constexpr double kFocal = 400;

// A link from frame a to frame b: a grid of a's pixels and where `a_pose`, `b_pose` put them in b.
PlaneLink LinkBetween(int a, int b, const PlanePose& a_pose, const PlanePose& b_pose) {
  const cv::Matx33d K = CameraMatrix(kFocal, kFrame);
  const cv::Matx33d H = PlaneToFrame(b_pose, K) * FrameToPlane(a_pose, K);
  PlaneLink l;
  l.a = a;
  l.b = b;
  for (int y = 40; y < kFrame.height; y += 70)
    for (int x = 40; x < kFrame.width; x += 90) {
      const cv::Vec3d q = H * cv::Vec3d(x, y, 1);
      const cv::Point2f to(float(q[0] / q[2]), float(q[1] / q[2]));
      if (to.x < 0 || to.y < 0 || to.x > kFrame.width - 1 || to.y > kFrame.height - 1) continue;
      l.in_a.emplace_back(float(x), float(y));
      l.in_b.push_back(to);
    }
  return l;
}

// Twelve frames in a row (150 px apart); the last six also linked to the first six by links that
// agree with each other and not with the chain, as if frame j lay 40 px past frame j - 6 (a
// look-alike stretch of ground). The solve starts where those links put the six.
struct PulledAway {
  std::vector<PlanePose> truth, start;
  std::vector<PlaneLink> links;
  std::vector<bool> chain;
  PulledAway() {
    const PlanePose reference = ReferencePose(CameraMatrix(kFocal, kFrame));
    for (int i = 0; i < 12; ++i) {
      PlanePose p = reference;
      p.centre[0] += 150.0 * i;
      truth.push_back(p);
      PlanePose wrong = p;
      if (i >= 6) wrong.centre[0] -= 6 * 150.0 - 40.0;
      start.push_back(wrong);
    }
    for (int i = 0; i + 1 < 12; ++i) {
      links.push_back(LinkBetween(i, i + 1, truth[size_t(i)], truth[size_t(i + 1)]));
      chain.push_back(true);
    }
    for (int j = 6; j < 12; ++j) {
      links.push_back(LinkBetween(j, j - 6, start[size_t(j)], truth[size_t(j - 6)]));
      chain.push_back(false);
    }
  }
};

PlaneAdjustmentOptions Robust() {
  PlaneAdjustmentOptions o;
  o.loss = "cauchy";
  o.per_link = true;
  o.drop_link_px = 3.0;
  o.max_iterations = 200;
  return o;
}

// Trusted, the chain pulls the six back over hundreds of pixels and the look-alike links are the
// ones found false; without trust, the robust loss keeps the look-alike placement and drops the
// chain's link between the two groups (the failure that drew lanes of a 10,000-frame survey at
// the wrong scale).
TEST(PlaneAdjustment, TrustedChainPullsAGroupBackFromLinksThatAgreeWithEachOther) {
  PulledAway s;
  for (bool trusted : {false, true}) {
    std::vector<PlaneLink> links = s.links;
    for (size_t k = 0; k < links.size(); ++k) links[k].trusted = trusted && s.chain[k];
    std::vector<PlanePose> poses = s.start;
    double focal = kFocal;
    const PlaneAdjustment r = AdjustPlanePoses(&poses, &focal, kFrame, links, 0, {}, {}, Robust());
    ASSERT_TRUE(r.ok) << r.message;
    double worst = 0;
    for (size_t i = 0; i < poses.size(); ++i) worst = std::max(worst, cv::norm(poses[i].centre - s.truth[i].centre));
    int chain_dropped = 0, others_dropped = 0;
    for (size_t k = 0; k < links.size(); ++k) (s.chain[k] ? chain_dropped : others_dropped) += r.dropped[k];
    if (trusted) {
      EXPECT_LT(worst, 1.0);
      EXPECT_EQ(chain_dropped, 0);
      EXPECT_GE(others_dropped, 1);
      // The look-alike links are found false, or left far off and discounted: none is satisfied.
      for (size_t k = 0; k < links.size(); ++k)
        if (!s.chain[k] && !r.dropped[k]) EXPECT_GT(PlaneTransferRms(poses, focal, kFrame, {links[k]}), 10.0) << k;
    } else {
      EXPECT_GT(worst, 100.0);
      EXPECT_GE(chain_dropped, 1);
    }
  }
}

// A pair of weight w counts as w^2 pairs, in the transfer error as in the solve: a link whose
// pair of weight 3 is 2 px off and whose other pair is exact has an RMS of sqrt(9 * 4 / 10).
TEST(PlaneAdjustment, PairWeightsCountAsThatManyPairs) {
  const PlanePose a = ReferencePose(CameraMatrix(kFocal, kFrame));
  PlanePose b = a;
  b.centre[0] += 100;
  PlaneLink l = LinkBetween(0, 1, a, b);
  ASSERT_GE(l.in_a.size(), 2u);
  l.in_a.resize(2);
  l.in_b.resize(2);
  l.in_b[1].x += 2;
  const std::vector<PlanePose> poses{a, b};
  EXPECT_NEAR(PlaneTransferRms(poses, kFocal, kFrame, {l}), std::sqrt(4.0 / 2), 1e-3);
  l.pair_weight = {1.0f, 3.0f};
  EXPECT_NEAR(PlaneTransferRms(poses, kFocal, kFrame, {l}), std::sqrt(9 * 4.0 / 10), 1e-3);
  // The scatter of the pairs they stand for counts too: 1 px on each of the 10.
  l.scatter_px = 1.0;
  EXPECT_NEAR(PlaneTransferRms(poses, kFocal, kFrame, {l}), std::sqrt((9 * 4.0 + 10) / 10), 1e-3);
}

// Ten frames in a row, 120 px apart, rolled and pitched by a few degrees each, linked to the next
// two; the solve starts from level cameras where the frames are, with a focal length taken for
// 70 degrees across when the camera's is 90 (LinkBetween's).
struct Jittered {
  std::vector<PlanePose> truth, start;
  std::vector<PlaneLink> links;
  explicit Jittered(double jitter_deg) {
    const PlanePose reference = ReferencePose(CameraMatrix(kFocal, kFrame));
    const double turns[10][2] = {{0, 0}, {3, -2}, {-4, 1}, {2, 4}, {-1, -4}, {4, 2}, {-3, -3}, {1, 3}, {-4, 0}, {3, -1}};
    for (int i = 0; i < 10; ++i) {
      PlanePose p = reference;
      p.centre[0] += 120.0 * i;
      if (i > 0) {
        p.pitch = turns[i][0] * jitter_deg / 4 * CV_PI / 180;
        p.roll = turns[i][1] * jitter_deg / 4 * CV_PI / 180;
      }
      truth.push_back(p);
      PlanePose level = p;
      level.pitch = level.roll = 0;
      start.push_back(i == 0 ? p : level);
    }
    for (int i = 0; i < 10; ++i)
      for (int j = i + 1; j <= std::min(9, i + 2); ++j) links.push_back(LinkBetween(j, i, truth[size_t(j)], truth[size_t(i)]));
  }
};

TEST(PlaneAdjustment, TheFocalLengthIsEstimatedWhereTheAttitudeChanges) {
  const double assumed = 0.5 * kFrame.width / std::tan(35.0 * CV_PI / 180);  // 286 px, for 400
  Jittered s(4.0);
  PlaneAdjustmentOptions o;
  o.max_iterations = 200;
  std::vector<PlanePose> held = s.start;
  double fixed = assumed;
  const PlaneAdjustment with_assumed = AdjustPlanePoses(&held, &fixed, kFrame, s.links, 0, {}, {}, o);
  ASSERT_TRUE(with_assumed.ok) << with_assumed.message;
  EXPECT_EQ(fixed, assumed);
  o.refine_focal = true;
  std::vector<PlanePose> poses = s.start;
  double focal = assumed;
  const PlaneAdjustment estimated = AdjustPlanePoses(&poses, &focal, kFrame, s.links, 0, {}, {}, o);
  ASSERT_TRUE(estimated.ok) << estimated.message;
  EXPECT_NEAR(focal, kFocal, 0.01 * kFocal);
  EXPECT_LT(estimated.final_rms_px, 0.05);
  // Held at the wrong one, the links cannot all be met.
  EXPECT_GT(with_assumed.final_rms_px, 10 * estimated.final_rms_px);
}

TEST(PlaneAdjustment, AFocalLengthTheLinksDoNotShowStaysWithinItsBounds) {
  // Level cameras in a row: any focal length fits the links as well; it stays within a factor of
  // 3 of where it starts.
  Jittered s(0.0);
  PlaneAdjustmentOptions o;
  o.refine_focal = true;
  std::vector<PlanePose> poses = s.start;
  double focal = 250;
  const PlaneAdjustment r = AdjustPlanePoses(&poses, &focal, kFrame, s.links, 0, {}, {}, o);
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_GE(focal, 250.0 / 3);
  EXPECT_LE(focal, 250.0 * 3);
  EXPECT_LT(r.final_rms_px, 0.05);
}

}  // namespace
}  // namespace rolamos
