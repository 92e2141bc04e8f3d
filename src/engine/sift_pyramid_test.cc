#include "engine/sift_pyramid.h"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

// OpenCV 4.6's SIFT pyramid, from its public calls.
std::vector<std::vector<cv::Mat>> OpenCvsPyramid(const cv::Mat& grey, int octaves) {
  cv::Mat f, twice, base;
  grey.convertTo(f, CV_32F);
  cv::resize(f, twice, cv::Size(f.cols * 2, f.rows * 2), 0, 0, cv::INTER_LINEAR);
  const float diff = std::sqrt(std::max(1.6f * 1.6f - 0.25f * 4, 0.01f));
  cv::GaussianBlur(twice, base, cv::Size(), diff, diff);
  std::vector<std::vector<cv::Mat>> p(static_cast<size_t>(octaves), std::vector<cv::Mat>(6));
  const double k = std::pow(2., 1. / 3);
  for (int o = 0; o < octaves; ++o)
    for (int i = 0; i < 6; ++i) {
      if (o == 0 && i == 0) {
        p[0][0] = base;
      } else if (i == 0) {
        const cv::Mat& src = p[size_t(o - 1)][3];
        cv::resize(src, p[size_t(o)][0], cv::Size(src.cols / 2, src.rows / 2), 0, 0, cv::INTER_NEAREST);
      } else {
        const double prev = std::pow(k, double(i - 1)) * 1.6, total = prev * k;
        const double sig = std::sqrt(total * total - prev * prev);
        cv::GaussianBlur(p[size_t(o)][size_t(i - 1)], p[size_t(o)][size_t(i)], cv::Size(), sig, sig);
      }
    }
  return p;
}

// The doubled first octave's image is cv::resize's, to the bit: odd and even sizes, down to two
// pixels (the ends clamp), and sizes past a vector's width.
TEST(SiftPyramid, DoublingIsCvResizes) {
  cv::RNG rng(9);
  for (const cv::Size size : {cv::Size(463, 345), cv::Size(400, 300), cv::Size(17, 2), cv::Size(2, 5), cv::Size(33, 18)}) {
    cv::Mat f(size, CV_32F);
    rng.fill(f, cv::RNG::UNIFORM, 0, 255);
    cv::Mat theirs;
    cv::resize(f, theirs, cv::Size(f.cols * 2, f.rows * 2), 0, 0, cv::INTER_LINEAR);
    const cv::Mat ours = DoubleLinear(f);
    ASSERT_EQ(ours.size(), theirs.size());
    EXPECT_EQ(cv::countNonZero(ours != theirs), 0) << size;
  }
}

// The blur is OpenCV's arithmetic in OpenCV's order: the same images to the last bit, at every
// octave (down to images smaller than the kernel).
TEST(SiftPyramid, IsOpenCvsPyramid) {
  cv::Mat grey;
  cv::cvtColor(RenderSeafloor(0, 0, 463, 345), grey, cv::COLOR_BGR2GRAY);
  const cv::Mat base = SiftBaseImage(grey, true, 1.6f);
  const int octaves = 8;
  const auto ours = SiftGaussianPyramid(base, octaves, 3, 5, 1.6);
  const auto theirs = OpenCvsPyramid(grey, octaves);
  double worst = 0;
  long differing = 0, total = 0;
  for (int o = 0; o < octaves; ++o)
    for (int i = 0; i < 6; ++i) {
      const cv::Mat& a = ours[size_t(o)][size_t(i)];
      const cv::Mat& b = theirs[size_t(o)][size_t(i)];
      ASSERT_EQ(a.size(), b.size()) << "octave " << o << " layer " << i;
      cv::Mat d;
      cv::absdiff(a, b, d);
      double m = 0;
      cv::minMaxLoc(d, nullptr, &m);
      worst = std::max(worst, m);
      differing += cv::countNonZero(d);
      total += long(d.total());
    }
  std::printf("%ld of %ld values differ from OpenCV's, by at most %g grey levels\n", differing, total, worst);
  EXPECT_EQ(worst, 0);
  EXPECT_EQ(differing, 0);
}

}  // namespace
}  // namespace rolamos
