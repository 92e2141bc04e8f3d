#include "engine/egomotion.h"

#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "engine/features.h"
#include "engine/motion_gate.h"
#include "engine/stage_options.h"
#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

const cv::Matx33d kK(600, 0, 319.5, 0, 600, 239.5, 0, 0, 1);

// Correspondences of a plane seen from two poses, with outliers mixed in.
void PlanePairs(const cv::Matx33d& H, int n, int outliers, std::vector<cv::Point2f>* a,
                std::vector<cv::Point2f>* b) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> ux(0, 640), uy(0, 480);
  std::normal_distribution<float> noise(0, 0.3f);
  for (int i = 0; i < n + outliers; ++i) {
    cv::Point2f p(ux(rng), uy(rng));
    cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
    cv::Point2f t(static_cast<float>(q[0] / q[2]) + noise(rng), static_cast<float>(q[1] / q[2]) + noise(rng));
    if (i >= n) t = cv::Point2f(ux(rng), uy(rng));
    a->push_back(p);
    b->push_back(t);
  }
}

TEST(Egomotion, RecoversHomographyAndDropsOutliers) {
  const cv::Matx33d H(0.98, -0.05, 35, 0.05, 0.98, -12, 1e-5, 2e-5, 1);
  std::vector<cv::Point2f> a, b;
  PlanePairs(H, 300, 120, &a, &b);
  EgomotionResult r = EstimateEgomotion(a, b, kK, EgomotionOptions{});
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_EQ(r.matches, 420);
  EXPECT_GE(r.inliers, 280);
  EXPECT_LE(r.inliers, 305);
  EXPECT_LT(r.bilateral_error_mean, 1.5);
  for (cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(639, 479), cv::Point2d(320, 240)}) {
    cv::Vec3d u = r.H * cv::Vec3d(p.x, p.y, 1), v = H * cv::Vec3d(p.x, p.y, 1);
    EXPECT_LT(std::hypot(u[0] / u[2] - v[0] / v[2], u[1] / u[2] - v[1] / v[2]), 0.3);
  }
  ASSERT_TRUE(r.motion.has_value());
}

TEST(Egomotion, BilateralEpipolarErrorIsZeroOnTheEpipolarLines) {
  // Pure sideways translation: F = [t]x, epipolar lines are horizontal.
  const cv::Matx33d F(0, 0, 0, 0, 0, -1, 0, 1, 0);
  EXPECT_NEAR(BilateralEpipolarError(F, {10, 20}, {50, 20}), 0.0, 1e-9);
  EXPECT_NEAR(BilateralEpipolarError(F, {10, 20}, {50, 23}), 6.0, 1e-9);  // 3 px each way
}

TEST(Egomotion, DecompositionKeepsThePhysicalSolution) {
  // Camera 1 at the origin looking down at a plane 10 units away; camera 2 moved sideways and
  // rotated 5 degrees about the optical axis. H = K (R - t n^T / d) K^-1.
  const double a = 5 * CV_PI / 180;
  const cv::Matx33d R(std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1);
  const cv::Vec3d t(0.8, 0.3, 0), n(0, 0, 1);
  const double d = 10;
  const cv::Matx33d H = kK * (R - (1.0 / d) * cv::Matx33d(t[0] * n[0], t[0] * n[1], t[0] * n[2],
                                                          t[1] * n[0], t[1] * n[1], t[1] * n[2],
                                                          t[2] * n[0], t[2] * n[1], t[2] * n[2])) *
                        kK.inv();
  std::vector<cv::Point2f> p1, p2;
  PlanePairs(H, 100, 0, &p1, &p2);
  auto m = DecomposeHomography(H, kK, p1, p2);
  ASSERT_TRUE(m.has_value());
  EXPECT_NEAR(std::abs(m->n[2]), 1.0, 1e-3);
  const double angle = std::atan2(m->R(1, 0), m->R(0, 0));
  EXPECT_NEAR(angle, a, 1e-3);
  EXPECT_NEAR(m->t[0] / m->t[1], t[0] / t[1], 1e-2);  // translation up to scale
}

TEST(Egomotion, TooFewMatchesIsAReasonNotACrash) {
  std::vector<cv::Point2f> a{{1, 1}, {2, 2}}, b{{1, 1}, {2, 2}};
  EgomotionResult r = EstimateEgomotion(a, b, kK, EgomotionOptions{});
  EXPECT_FALSE(r.ok);
  EXPECT_EQ(r.failure, "too_few_matches");
}

// Few matches that nearly all agree are a true registration (low-contrast ground, a small
// overlap: skerki6's last frame, 17 of 21); as many matches at random are not, nor two thirds of a
// small set agreeing.
TEST(Egomotion, FewMatchesThatNearlyAllAgreeAreEnoughAndRandomOnesAreNot) {
  const cv::Matx33d H(0.98, -0.05, 35, 0.05, 0.98, -12, 1e-5, 2e-5, 1);
  const EgomotionOptions o;
  EXPECT_EQ(o.RequiredInliers(15), 15);
  EXPECT_EQ(o.RequiredInliers(21), 16);
  EXPECT_EQ(o.RequiredInliers(40), o.min_inliers);
  EXPECT_EQ(o.RequiredInliers(300), o.min_inliers);
  std::vector<cv::Point2f> a, b;
  PlanePairs(H, 17, 4, &a, &b);
  EgomotionResult r = EstimateEgomotion(a, b, kK, o);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_GE(r.inliers, 16);
  for (cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(639, 479)}) {
    cv::Vec3d u = r.H * cv::Vec3d(p.x, p.y, 1), v = H * cv::Vec3d(p.x, p.y, 1);
    EXPECT_LT(std::hypot(u[0] / u[2] - v[0] / v[2], u[1] / u[2] - v[1] / v[2]), 1.5);
  }
  a.clear();
  b.clear();
  PlanePairs(H, 0, 21, &a, &b);
  EXPECT_FALSE(EstimateEgomotion(a, b, kK, o).ok);
  a.clear();
  b.clear();
  PlanePairs(H, 20, 10, &a, &b);  // 20 of 30 agree: 23 needed
  EXPECT_FALSE(EstimateEgomotion(a, b, kK, o).ok);
  a.clear();
  b.clear();
  PlanePairs(H, 12, 2, &a, &b);  // 14 matches: too few, however well they agree
  EgomotionResult few = EstimateEgomotion(a, b, kK, o);
  EXPECT_FALSE(few.ok);
  EXPECT_EQ(few.failure, "too_few_matches");
}

// A user's --min-inliers under the few-matches floor is what is asked of any set, and valid.
TEST(Egomotion, AMinimumUnderTheFewMatchesFloorHoldsForEverySet) {
  MosaickerOptions m;
  m.min_inliers = 12;
  const EgomotionOptions o = ToEgomotionOptions(m);
  std::string error;
  EXPECT_TRUE(o.IsValid(&error)) << error;
  EXPECT_EQ(o.RequiredInliers(14), 12);
  EXPECT_EQ(o.RequiredInliers(300), 12);
}

TEST(Features, MatchAShiftedViewOfTheSeafloor) {
  cv::Mat ground = RenderSeafloor(0, 0, 800, 600);
  cv::Mat gray;
  cv::cvtColor(ground, gray, cv::COLOR_BGR2GRAY);
  cv::Mat a = gray(cv::Rect(0, 0, 640, 480)), b = gray(cv::Rect(60, 40, 640, 480));
  for (const std::string type : {"sift", "orb", "akaze"}) {
    FeatureOptions o;
    o.type = type;
    FeatureExtractor fx(o);
    Features fa = fx.Extract(a), fb = fx.Extract(b);
    ASSERT_GT(fa.points.size(), 100u) << type;
    Matches m = MatchFeatures(fa, fb, o);
    ASSERT_GT(m.from.size(), 40u) << type;
    // ORB keypoints come from coarse pyramid levels: looser localisation, RANSAC copes.
    const double tolerance = type == "orb" ? 4.0 : 1.5;
    int good = 0;
    for (size_t i = 0; i < m.from.size(); ++i)
      good += std::hypot(m.from[i].x - 60 - m.to[i].x, m.from[i].y - 40 - m.to[i].y) < tolerance;
    EXPECT_GT(double(good) / m.from.size(), 0.9) << type;
  }
  FeatureOptions bad;
  bad.type = "surf";
  std::string error;
  EXPECT_FALSE(bad.IsValid(&error));
}

TEST(MotionGate, PassesSmoothMotionAndFlagsATurnAbout) {
  MotionGate gate(MotionGateOptions{}, cv::Size(640, 480));
  auto check = [&](const FrameMotion& m) {
    gate.Predict();
    const GateVerdict v = gate.Evaluate(m);
    if (v.consistent) gate.Accept(m);
    else gate.Skip();
    return v.consistent;
  };
  for (int i = 0; i < 20; ++i) {
    FrameMotion m;
    m.dx = 0.5 * i;  // a slow, steady acceleration
    m.dy = 60;
    EXPECT_TRUE(check(m)) << i;
  }
  FrameMotion turn;
  turn.dx = 10;
  turn.dy = 60;
  turn.rotation = CV_PI;  // a 180-degree turn between two frames
  EXPECT_FALSE(check(turn));
  FrameMotion jump;
  jump.dx = 10;
  jump.dy = 400;  // most of a frame in one step
  EXPECT_FALSE(check(jump));
  FrameMotion next;
  next.dx = 10.5;
  next.dy = 60;
  EXPECT_TRUE(check(next));
}

TEST(MotionGate, AnAcceptedUnpredictedMotionRestartsTheFilter) {
  MotionGate gate(MotionGateOptions{}, cv::Size(640, 480));
  FrameMotion forward;
  forward.dy = 60;
  for (int i = 0; i < 10; ++i) {
    gate.Predict();
    EXPECT_TRUE(gate.Evaluate(forward).consistent);
    gate.Accept(forward);
  }
  // The vehicle turns about (a lane join without turn frames) and the registration is well
  // supported: the engine keeps it, and the filter follows the new motion from then on.
  FrameMotion back;
  back.dy = -60;
  back.rotation = CV_PI;
  gate.Predict();
  EXPECT_FALSE(gate.Evaluate(back).consistent);
  gate.Accept(back);
  for (int i = 0; i < 5; ++i) {
    gate.Predict();
    EXPECT_TRUE(gate.Evaluate(back).consistent) << i;
    gate.Accept(back);
  }
}

TEST(MotionGate, LearnsTheJitterItObserves) {
  const cv::Size frame(800, 600);
  MotionGate calm(MotionGateOptions{}, frame), shaky(MotionGateOptions{}, frame);
  std::mt19937 rng(3);
  std::normal_distribution<double> jitter(0.0, 40.0);  // roll and pitch drawn per frame
  for (int i = 0; i < 60; ++i) {
    FrameMotion steady, noisy;
    steady.dy = noisy.dy = 180;
    noisy.dx = jitter(rng);
    noisy.dy += jitter(rng);
    calm.Predict();
    calm.Accept(steady);
    shaky.Predict();
    shaky.Accept(noisy);
  }
  EXPECT_GT(shaky.jitter_px(), 2 * calm.jitter_px());
  // A deviation of three times the observed jitter passes the shaky gate.
  FrameMotion big;
  big.dx = 3 * 40.0;
  big.dy = 180;
  shaky.Predict();
  EXPECT_TRUE(shaky.Evaluate(big).consistent);
}

TEST(MotionGate, MotionOfAHomography) {
  const double a = 0.1;
  const cv::Matx33d H(1.1 * std::cos(a), -1.1 * std::sin(a), 0, 1.1 * std::sin(a), 1.1 * std::cos(a), 0, 0, 0, 1);
  FrameMotion m = MotionOf(H, cv::Size(101, 101));
  EXPECT_NEAR(m.rotation, a, 1e-9);
  EXPECT_NEAR(m.log_scale, std::log(1.1), 1e-9);
}

}  // namespace
}  // namespace rolamos
