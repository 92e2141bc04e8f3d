#include "engine/bilateral_filter.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

struct Difference {
  double max = 0;
  int pixels = 0;  // channel values that differ
};

Difference Compare(const cv::Mat& image, int diameter, double sigma_color, double sigma_space) {
  cv::Mat ours, theirs;
  BilateralFilter(image, ours, diameter, sigma_color, sigma_space);
  cv::bilateralFilter(image, theirs, diameter, sigma_color, sigma_space);
  EXPECT_EQ(ours.type(), theirs.type());
  EXPECT_EQ(ours.size(), theirs.size());
  cv::Mat diff;
  cv::absdiff(ours, theirs, diff);
  Difference d;
  cv::minMaxLoc(diff.reshape(1), nullptr, &d.max);
  d.pixels = cv::countNonZero(diff.reshape(1));
  return d;
}

// The engine's filter on seafloor: OpenCV's result at the engine's settings and around them,
// value for value but where a weight left out tips a rounding (1 value in 700,000 here, by one
// grey level); widths that leave a tail of fewer than sixteen pixels on each row.
TEST(BilateralFilter, IsOpenCvsOnSeafloor) {
  const cv::Mat ground = RenderSeafloor(100, 200, 803, 301);
  SCOPED_TRACE(FastBilateralApplies(ground, 12.0) ? "fast path" : "OpenCV's path (no AVX-512 here)");
  for (int diameter : {3, 5, 7}) {
    for (double sigma_color : {6.0, 12.0}) {
      SCOPED_TRACE("diameter " + std::to_string(diameter) + ", sigma_color " + std::to_string(sigma_color));
      const Difference d = Compare(ground, diameter, sigma_color, 3.0);
      EXPECT_LE(d.max, 1);
      EXPECT_LE(d.pixels, int(ground.total() * 3) / 100000) << d.pixels << " values differ";
    }
  }
  const cv::Mat narrow = ground(cv::Rect(5, 7, 13, 9)).clone();  // narrower than one vector
  EXPECT_EQ(Compare(narrow, 5, 12.0, 3.0).max, 0);
}

// Noise, where neighbours differ most: the colour weights left out (differences over 62) can
// move a value by one grey level only where OpenCV's sits on a rounding boundary.
TEST(BilateralFilter, NoiseDiffersByAtMostOneGreyLevelRarely) {
  cv::Mat noise(240, 320, CV_8UC3);
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::NORMAL, cv::Scalar::all(128), cv::Scalar::all(40));
  const Difference d = Compare(noise, 5, 12.0, 3.0);
  EXPECT_LE(d.max, 1);
  EXPECT_LE(d.pixels, int(noise.total()) / 1000);
}

// What the fast path does not cover is OpenCV's own: grey frames, a wide colour sigma.
TEST(BilateralFilter, OtherFramesAndSettingsAreOpenCvs) {
  const cv::Mat ground = RenderSeafloor(0, 0, 200, 150);
  cv::Mat gray;
  cv::cvtColor(ground, gray, cv::COLOR_BGR2GRAY);
  EXPECT_FALSE(FastBilateralApplies(gray, 12.0));
  EXPECT_FALSE(FastBilateralApplies(ground, 40.0));
  EXPECT_EQ(Compare(gray, 5, 12.0, 3.0).pixels, 0);
  EXPECT_EQ(Compare(ground, 5, 40.0, 3.0).pixels, 0);
}

// In place, as the preprocessor may call it.
TEST(BilateralFilter, InPlaceIsTheSame) {
  const cv::Mat ground = RenderSeafloor(0, 0, 160, 120);
  cv::Mat expected, image = ground.clone();
  BilateralFilter(ground, expected, 5, 12.0, 3.0);
  BilateralFilter(image, image, 5, 12.0, 3.0);
  EXPECT_EQ(cv::norm(image, expected, cv::NORM_INF), 0);
}

}  // namespace
}  // namespace rolamos
