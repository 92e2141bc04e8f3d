#include "engine/colour.h"
#include "util/exposure_gains.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

// A lighting pattern fixed in the frame: darker corners and a bright spot left of the centre.
cv::Mat Lighting(cv::Size s) {
  cv::Mat l(s, CV_32F);
  for (int y = 0; y < s.height; ++y)
    for (int x = 0; x < s.width; ++x) {
      const double r2 = (std::pow(x - s.width / 2.0, 2) + std::pow(y - s.height / 2.0, 2)) / std::pow(s.width / 2.0, 2);
      const double d2 = (std::pow(x - 0.35 * s.width, 2) + std::pow(y - 0.6 * s.height, 2)) / std::pow(0.3 * s.width, 2);
      l.at<float>(y, x) = static_cast<float>((1 - 0.35 * r2) * (0.7 + 0.5 * std::exp(-0.5 * d2)));
    }
  return l;
}

cv::Mat Lit(const cv::Mat& ground, const cv::Mat& light, const cv::Scalar& cast = cv::Scalar(1, 1, 1)) {
  cv::Mat f, l3;
  ground.convertTo(f, CV_32F);
  cv::merge(std::vector<cv::Mat>{light, light, light}, l3);
  f = f.mul(l3);
  cv::multiply(f, cast, f);
  cv::Mat out;
  f.convertTo(out, CV_8U);
  return out;
}

TEST(Colour, LearnsTheLightingTheFramesShare) {
  const cv::Size s(320, 240);
  const cv::Mat light = Lighting(s);
  ColourOptions o;
  o.water_colour = false;
  ColourModel model(o);
  const cv::Mat ground = RenderSeafloor(0, 0, 2000, 1200);
  for (int i = 0; i < 40; ++i) model.Add(Lit(ground(cv::Rect(37 * i % 1600, 23 * i % 900, 320, 240)), light), {});
  ASSERT_TRUE(model.frozen());
  const cv::Mat c = model.Correction(s);
  // correction x lighting is flat: its spread across the frame is a small part of the lighting's.
  std::vector<cv::Mat> ch;
  cv::split(c, ch);
  const cv::Mat flat = ch[1].mul(light);
  cv::Scalar m, sd, lm, lsd;
  cv::meanStdDev(flat, m, sd);
  cv::meanStdDev(light, lm, lsd);
  EXPECT_LT(sd[0] / m[0], 0.25 * lsd[0] / lm[0]) << "left " << sd[0] / m[0] << " of " << lsd[0] / lm[0];
  // Kept in the store and read back as it was.
  const ColourModel again = ColourModel::FromJson(model.ToJson(), o, "lighting.json");
  EXPECT_LT(cv::norm(again.Correction(s), c, cv::NORM_INF), 1e-4);
}

TEST(Colour, ExposureGainsMatchOverlappingFrames) {
  const cv::Mat ground = RenderSeafloor(0, 0, 900, 400);
  std::vector<cv::Mat> small;
  std::vector<cv::Matx33d> placements;
  const double exposure[] = {1.0, 1.25, 0.8, 1.1};
  for (int i = 0; i < 4; ++i) {
    cv::Mat f;
    ground(cv::Rect(150 * i, 0, 400, 300)).convertTo(f, CV_32F, exposure[i]);
    cv::Mat s;
    cv::resize(f, s, cv::Size(), 0.125, 0.125, cv::INTER_AREA);
    small.push_back(s);
    placements.push_back(cv::Matx33d(1, 0, 150.0 * i, 0, 1, 0, 0, 0, 1));
  }
  const std::vector<double> g = SolveExposureGains(small, 0.125, placements, 0.01);
  ASSERT_EQ(g.size(), 4u);
  for (int i = 1; i < 4; ++i) EXPECT_NEAR(g[i] * exposure[i] / (g[0] * exposure[0]), 1.0, 0.03) << i;
  double mean_log = 0;
  for (double x : g) mean_log += std::log(x);
  EXPECT_NEAR(mean_log / 4, 0.0, 0.02);  // the patch does not drift darker or lighter
}

TEST(Colour, OneColourBlackAndBurntFramesStayFinite) {
  const cv::Size s(160, 120);
  ColourModel model(ColourOptions{});
  for (int i = 0; i < 20; ++i) model.Add(cv::Mat(s, CV_8UC3, cv::Scalar(40, 160, 60)), {});  // green sand, all of it
  for (int i = 0; i < 5; ++i) model.Add(cv::Mat::zeros(s, CV_8UC3), {});
  for (int i = 0; i < 5; ++i) model.Add(cv::Mat(s, CV_8UC3, cv::Scalar::all(255)), {});
  const cv::Mat c = model.Correction(s);
  EXPECT_TRUE(cv::checkRange(c));
  double lo, hi;
  cv::minMaxLoc(c.reshape(1), &lo, &hi);
  EXPECT_GT(lo, 0.1);
  EXPECT_LT(hi, 10.0);
  // A seafloor that is green is not made grey: the balance stays within its bounds.
  const cv::Vec3f centre = c.at<cv::Vec3f>(60, 80);
  EXPECT_LT(centre[0] / centre[1], 2.6f);
}

}  // namespace
}  // namespace rolamos
