#include "engine/ecc_translation.h"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

struct Pair {
  cv::Mat templ, input, mask;
};

// A seafloor and the same seafloor moved by `shift` (template pixel p is input pixel p + shift),
// both as float; the input's mask leaves out a border and a hole, where the input is 0.
Pair Shifted(cv::Size size, cv::Point2d shift, uint32_t seed, bool masked = true) {
  const cv::Mat grey = test::MakeImage(size.width + 40, size.height + 40, 1, 8, seed);
  cv::Mat f;
  grey.convertTo(f, CV_32F);
  // Smooth enough for cubic resampling to move it exactly.
  cv::GaussianBlur(f, f, cv::Size(), 3.0);
  f -= cv::mean(f);  // the engine's images are high-passed
  Pair p;
  // Template pixel p reads the seafloor at p + 20, input pixel q at q + 20 - shift: p is q + shift.
  const cv::Matx23d at(1, 0, 20, 0, 1, 20), back(1, 0, 20 - shift.x, 0, 1, 20 - shift.y);
  cv::warpAffine(f, p.templ, at, size, cv::INTER_CUBIC | cv::WARP_INVERSE_MAP);
  cv::warpAffine(f, p.input, back, size, cv::INTER_CUBIC | cv::WARP_INVERSE_MAP);
  if (!masked) return p;
  p.mask = cv::Mat(size, CV_8U, cv::Scalar(0));
  p.mask(cv::Rect(4, 4, size.width - 8, size.height - 8)).setTo(255);
  cv::circle(p.mask, cv::Point(size.width / 3, size.height / 2), size.height / 6, 0, -1);
  // Nothing where the mask is not: the engine's view of the patch image is empty there.
  p.input.setTo(0, p.mask == 0);
  return p;
}

TEST(EccTranslation, FindsWhatOpenCvsEccFinds) {
  for (const auto& [size, shift] : {std::pair{cv::Size(323, 241), cv::Point2d(1.3, -0.7)},
                                    {cv::Size(200, 150), cv::Point2d(-0.45, 2.2)},
                                    {cv::Size(97, 61), cv::Point2d(0.8, 0.15)}}) {
    const Pair p = Shifted(size, shift, 5 + uint32_t(size.width));
    cv::Mat W = cv::Mat::eye(2, 3, CV_32F);
    const cv::TermCriteria stop(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 15, 1e-4);
    const double theirs = cv::findTransformECC(p.templ, p.input, W, cv::MOTION_TRANSLATION, stop, p.mask, 3);
    const EccTranslation ours = FindEccTranslation(p.templ, p.input, p.mask, {0, 0}, 15, 1e-4);
    ASSERT_TRUE(ours.ok) << ours.failure;
    EXPECT_GE(ours.iterations, 2);
    EXPECT_NEAR(ours.correlation, theirs, 2e-3) << size;
    // Sampled where OpenCV samples, each step is OpenCV's up to the rounding of its sums.
    EXPECT_NEAR(ours.shift.x, W.at<float>(0, 2), 1e-3) << size;
    EXPECT_NEAR(ours.shift.y, W.at<float>(1, 2), 1e-3) << size;
    std::printf("%d x %d: truth %.3f %.3f, ours %.4f %.4f (%d steps), OpenCV's %.4f %.4f\n", size.width, size.height,
                shift.x, shift.y, ours.shift.x, ours.shift.y, ours.iterations, W.at<float>(0, 2), W.at<float>(1, 2));
  }
}

// Bilinear sampling biases ECC towards whole and half pixels by up to ~0.05 pixel between them
// (OpenCV's the same), and a mask's edges pull it; at half pixels, unmasked, it must reach the truth
// within the 1/32 pixel its sampling positions are rounded to.
TEST(EccTranslation, ReachesTheTruthWhereSamplingIsUnbiased) {
  for (const auto& [shift, start] : {std::pair{cv::Point2d(1.5, -0.5), cv::Point2d(0, 0)},
                                     {cv::Point2d(3.5, -2.5), cv::Point2d(3, -2)},
                                     {cv::Point2d(-0.5, 2.0), cv::Point2d(0, 1.5)}}) {
    const Pair p = Shifted(cv::Size(160, 120), shift, 9, false);
    const EccTranslation r = FindEccTranslation(p.templ, p.input, cv::Mat(), start, 100, 1e-9);
    ASSERT_TRUE(r.ok) << r.failure;
    EXPECT_NEAR(r.shift.x, shift.x, 1.0 / 32) << shift;
    EXPECT_NEAR(r.shift.y, shift.y, 1.0 / 32) << shift;
  }
}

TEST(EccTranslation, ScalarAgreesWithTheVectorPath) {
  const Pair p = Shifted(cv::Size(211, 133), cv::Point2d(-1.1, 0.6), 21);
  const EccTranslation a = FindEccTranslation(p.templ, p.input, p.mask, {0, 0}, 15, 1e-4);
  const EccTranslation b = internal::FindEccTranslationScalar(p.templ, p.input, p.mask, {0, 0}, 15, 1e-4);
  ASSERT_TRUE(a.ok && b.ok);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_NEAR(a.shift.x, b.shift.x, 1e-4);
  EXPECT_NEAR(a.shift.y, b.shift.y, 1e-4);
  EXPECT_NEAR(a.correlation, b.correlation, 1e-5);
}

TEST(EccTranslation, SaysWhyItFails) {
  const Pair p = Shifted(cv::Size(120, 90), cv::Point2d(0.5, 0.5), 3);
  const cv::Mat flat(p.templ.size(), CV_32F, cv::Scalar(7));
  const EccTranslation a = FindEccTranslation(flat, p.input, p.mask, {0, 0}, 15, 1e-4);
  EXPECT_FALSE(a.ok);
  EXPECT_NE(a.failure.find("not a number"), std::string::npos) << a.failure;
  const EccTranslation b = FindEccTranslation(p.templ, p.input, p.mask, {30, 0}, 15, 1e-4);
  EXPECT_FALSE(b.ok);
  EXPECT_NE(b.failure.find("left the images"), std::string::npos) << b.failure;
  const cv::Mat none(p.templ.size(), CV_8U, cv::Scalar(0));
  const EccTranslation c = FindEccTranslation(p.templ, p.input, none, {0, 0}, 15, 1e-4);
  EXPECT_FALSE(c.ok);
  EXPECT_FALSE(c.failure.empty());
  EXPECT_ANY_THROW(FindEccTranslation(p.templ, p.input(cv::Rect(0, 0, 60, 60)), cv::Mat(), {0, 0}, 15, 1e-4));
  cv::Mat bytes;
  p.templ.convertTo(bytes, CV_8U);
  EXPECT_ANY_THROW(FindEccTranslation(bytes, p.input, cv::Mat(), {0, 0}, 15, 1e-4));
}

}  // namespace
}  // namespace rolamos
