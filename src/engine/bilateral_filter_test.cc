#include "engine/bilateral_filter.h"

#include <algorithm>
#include <cmath>

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

// The fast path's own sums, by the book: each neighbour within the radius in OpenCV's order,
// weight = colour (the 64-entry table, 0 from a difference of 63) x space in float, each value
// multiplied in and added by one fused multiply-add, as the vector steps do (32 and 16 pixels);
// in a row's last width % 16 pixels, the product rounded and then added.
cv::Mat FastPathByTheBook(const cv::Mat& src, int radius, double sigma_color, double sigma_space) {
  float table[64] = {};
  for (int i = 0; i < 63; ++i) table[i] = static_cast<float>(std::exp(i * i * (-0.5 / (sigma_color * sigma_color))));
  cv::Mat padded;
  cv::copyMakeBorder(src, padded, radius, radius, radius, radius, cv::BORDER_REFLECT_101);
  cv::Mat out(src.size(), CV_8UC3);
  for (int y = 0; y < src.rows; ++y)
    for (int x = 0; x < src.cols; ++x) {
      const cv::Vec3b c = padded.at<cv::Vec3b>(y + radius, x + radius);
      float sum[3] = {0, 0, 0}, ws = 0;
      for (int i = -radius; i <= radius; ++i)
        for (int j = -radius; j <= radius; ++j) {
          const double r = std::sqrt(double(i) * i + double(j) * j);
          if (r > radius) continue;
          const float space = static_cast<float>(std::exp(r * r * (-0.5 / (sigma_space * sigma_space))));
          const cv::Vec3b v = padded.at<cv::Vec3b>(y + radius + i, x + radius + j);
          const int d = std::abs(v[0] - c[0]) + std::abs(v[1] - c[1]) + std::abs(v[2] - c[2]);
          const float w = table[std::min(d, 63)] * space;
          ws += w;
          const bool fused = x < src.cols - src.cols % 16;
          for (int k = 0; k < 3; ++k) {
            const float product = w * float(v[k]);  // a statement of its own: never fused
            sum[k] = fused ? std::fma(w, float(v[k]), sum[k]) : sum[k] + product;
          }
        }
      const float inv = 1.f / ws;
      for (int k = 0; k < 3; ++k) out.at<cv::Vec3b>(y, x)[k] = static_cast<uchar>(cvRound(sum[k] * inv));
    }
  return out;
}

// Widths that take each step: 32 pixels (AVX-512 BW), 16, and a tail (1292 leaves 12).
TEST(BilateralFilter, FastPathIsItsSumsToTheBit) {
  const cv::Mat ground = RenderSeafloor(40, 60, 336, 90), wide = RenderSeafloor(0, 0, 1292, 24);
  const cv::Mat narrow = ground(cv::Rect(5, 7, 13, 9)).clone();
  cv::Mat noise(70, 219, CV_8UC3);
  cv::RNG rng(11);
  rng.fill(noise, cv::RNG::NORMAL, cv::Scalar::all(128), cv::Scalar::all(40));
  for (const cv::Mat* image : {&ground, &wide, &narrow, static_cast<const cv::Mat*>(&noise)}) {
    if (!FastBilateralApplies(*image, 12.0)) GTEST_SKIP() << "no AVX-512 here: OpenCV's path";
    for (int diameter : {3, 5, 7}) {
      cv::Mat ours;
      BilateralFilter(*image, ours, diameter, 12.0, 3.0);
      const cv::Mat book = FastPathByTheBook(*image, diameter / 2, 12.0, 3.0);
      EXPECT_EQ(cv::norm(ours, book, cv::NORM_INF), 0) << "diameter " << diameter << ", " << image->cols << " wide";
    }
  }
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
