#include "engine/registration.h"

#include <cmath>

#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

// The homography between two views of a plane from one camera centre, the second pitched by
// `pitch_deg` and rolled by `roll_deg`: K R K^-1, K of a frame `fov_deg` across.
cv::Matx33d Turned(cv::Size frame, double fov_deg, double pitch_deg, double roll_deg) {
  const double f = 0.5 * frame.width / std::tan(0.5 * fov_deg * CV_PI / 180);
  const cv::Matx33d K(f, 0, (frame.width - 1) / 2.0, 0, f, (frame.height - 1) / 2.0, 0, 0, 1);
  const double p = pitch_deg * CV_PI / 180, r = roll_deg * CV_PI / 180;
  const cv::Matx33d pitch(1, 0, 0, 0, std::cos(p), -std::sin(p), 0, std::sin(p), std::cos(p));
  const cv::Matx33d roll(std::cos(r), 0, std::sin(r), 0, 1, 0, -std::sin(r), 0, std::cos(r));
  return K * pitch * roll * K.inv();
}

TEST(Registration, AttitudeChangesAVehicleMakesBetweenFramesArePlausible) {
  const cv::Size frame(1292, 964);
  const SupportOptions o;
  // A 1292 x 964 video at 90 degrees across, rolled and pitched by 2 degrees anew at every frame:
  // two frames in a row differ by up to 8 degrees (bench/RESULTS.md, session 21).
  for (double fov : {50.0, 70.0, 90.0}) {
    for (const cv::Vec2d& turn : {cv::Vec2d(2, 0), cv::Vec2d(5, 0), cv::Vec2d(8, 0), cv::Vec2d(-8, 0),
                                 cv::Vec2d(0, 8), cv::Vec2d(5, 5), cv::Vec2d(-5, 5)})
      EXPECT_TRUE(IsPlausibleMotion(Turned(frame, fov, turn[0], turn[1]), frame, o))
          << fov << " degrees across, pitched " << turn[0] << ", rolled " << turn[1];
  }
}

TEST(Registration, MirrorsFoldsAndWildPerspectiveAreNot) {
  const cv::Size frame(800, 600);
  const SupportOptions o;
  EXPECT_TRUE(IsPlausibleMotion(cv::Matx33d::eye(), frame, o));
  // A mirror image.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(-1, 0, 799, 0, 1, 0, 0, 0, 1), frame, o));
  // The horizon inside the frame: the plane folds over.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(1, 0, 0, 0, 1, 0, 0, -1.0 / 300, 1), frame, o));
  // Scale across the frame changing by half again or more: a camera turned 20 degrees at 90
  // across in 1/30 s, or (far likelier) a false registration.
  EXPECT_FALSE(IsPlausibleMotion(Turned(frame, 90, 20, 0), frame, o));
  // Too much zoom, too much shear.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(2, 0, 0, 0, 2, 0, 0, 0, 1), frame, o));
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(1, 0.8, 0, 0, 1, 0, 0, 0, 1), frame, o));
}


TEST(Registration, ALoopLinkIsFoundWhereTheChainHasDriftedFromTheLaneBefore) {
  const cv::Size size(640, 480);
  // Frame 80 lies beside frame 39 of the lane before: 40 % of it across (b = 39's pixels).
  const cv::Matx33d truth(0.999, -0.02, 384, 0.02, 0.999, 12, 0, 0, 1);
  auto a = std::make_shared<Features>(), b = std::make_shared<Features>();
  test::TwoFeatureViews(truth, size, a.get(), b.get());
  PatchFrame older;
  older.index = 39;
  older.features = b;
  // The chain has placed frame 80 110 px along the lane from where it lies.
  const cv::Matx33d drifted = cv::Matx33d(1, 0, 0, 0, 1, 110, 0, 0, 1) * truth;
  const PatchFitOptions o;
  // The guided search alone (an empty size) looks within 48 px of the drifted placement.
  EXPECT_FALSE(LinkPair(80, *a, drifted, older, o, cv::Size(), nullptr));
  cv::Matx33d placed;
  const auto link = LinkPair(80, *a, drifted, older, o, size, &placed);
  ASSERT_TRUE(link);
  EXPECT_EQ(link->a, 80);
  EXPECT_EQ(link->b, 39);
  EXPECT_GE(link->in_a.size(), 100u);
  for (size_t i = 0; i < link->in_a.size(); ++i) {
    const cv::Vec3d q = truth * cv::Vec3d(link->in_a[i].x, link->in_a[i].y, 1);
    EXPECT_LT(std::hypot(q[0] / q[2] - link->in_b[i].x, q[1] / q[2] - link->in_b[i].y), 0.5) << i;
  }
  // The placement the link implies is the true one.
  const cv::Vec3d c = placed * cv::Vec3d(319.5, 239.5, 1), t = truth * cv::Vec3d(319.5, 239.5, 1);
  EXPECT_LT(std::hypot(c[0] / c[2] - t[0] / t[2], c[1] / c[2] - t[1] / t[2]), 0.5);
  // A lane further off than loop_drift (0.3 of the diagonal: 240 px) is not taken for this one.
  const cv::Matx33d far = cv::Matx33d(1, 0, 0, 0, 1, 300, 0, 0, 1) * truth;
  EXPECT_FALSE(LinkPair(80, *a, far, older, o, size, nullptr));
  PatchFitOptions guided_only;
  guided_only.loop_drift = 0;
  EXPECT_FALSE(LinkPair(80, *a, drifted, older, guided_only, size, nullptr));
}


// The trimmed fit both FitToPatch and the keyframe fit use: from a guess a few pixels off, pairs
// of which a fifth are wrong matches (tens of pixels off) give back the true homography, and the
// wrong ones are not kept; the links group the kept pairs by the frame they are on.
TEST(Registration, TheTrimmedFitRecoversTheHomographyAndDropsWrongPairs) {
  const cv::Matx33d truth(1.02, 0.03, 14.0, -0.02, 0.99, -6.0, 1e-5, -2e-5, 1);
  cv::RNG rng(3);
  PatchPairs pairs;
  std::vector<bool> wrong;
  for (int i = 0; i < 200; ++i) {
    const cv::Point2f p(rng.uniform(0.f, 800.f), rng.uniform(0.f, 600.f));
    const bool bad = i % 5 == 0;
    const cv::Point2d q = ApplyHomography(truth, p) +
                          (bad ? cv::Point2d(rng.uniform(20.0, 60.0), rng.uniform(-60.0, -20.0))
                               : cv::Point2d(rng.gaussian(0.2), rng.gaussian(0.2)));
    // Pairs on two frames: 7 and 9 (the patch frame's own point is not used by the fit).
    pairs.Add(p, cv::Matx33d::eye(), cv::Point2f(q), i % 2 ? 7 : 9);
    wrong.push_back(bad);
  }
  const cv::Matx33d guess = cv::Matx33d(1, 0, 3, 0, 1, -2, 0, 0, 1) * truth;
  const TrimmedFit fit = FitTrimmedHomography(pairs, guess, 2.0, 12.0);
  ASSERT_TRUE(fit.ok);
  EXPECT_LT(MaxCornerShift(fit.H, truth, cv::Size(800, 600)), 0.5);  // the guess: 3.6 px off
  int kept_wrong = 0, kept = 0;
  for (size_t i = 0; i < wrong.size(); ++i) {
    kept += fit.keep[i];
    kept_wrong += fit.keep[i] && wrong[i];
  }
  EXPECT_EQ(kept_wrong, 0);
  EXPECT_EQ(kept, fit.inliers);
  EXPECT_GE(kept, 150);
  const std::vector<FrameLink> links = LinksByFrame(42, pairs, fit.keep);
  ASSERT_EQ(links.size(), 2u);
  for (const FrameLink& l : links) {
    EXPECT_EQ(l.a, 42);
    EXPECT_TRUE(l.b == 7 || l.b == 9);
    EXPECT_EQ(l.in_a.size(), l.in_b.size());
  }
  EXPECT_EQ(static_cast<int>(links[0].in_a.size() + links[1].in_a.size()), kept);
  // Too few pairs: not ok, the guess unchanged.
  PatchPairs few;
  for (int i = 0; i < 11; ++i) few.Add(pairs.in_frame[size_t(i)], cv::Matx33d::eye(), pairs.in_patch[size_t(i)], 7);
  const TrimmedFit none = FitTrimmedHomography(few, guess, 2.0, 12.0);
  EXPECT_FALSE(none.ok);
  EXPECT_EQ(none.H, guess);
}

}  // namespace
}  // namespace rolamos
