#include "engine/corner_peaks.h"

#include <cmath>
#include <map>
#include <utility>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

// OpenCV's way, from its public calls: the response image, its local maxima within 5 x 5.
std::map<std::pair<int, int>, float> OpenCvsPeaks(const cv::Mat& gray, int border, float least) {
  cv::Mat eig, most;
  cv::cornerMinEigenVal(gray, eig, 3, 3);
  cv::dilate(eig, most, cv::Mat(), cv::Point(-1, -1), 2);
  std::map<std::pair<int, int>, float> peaks;
  for (int y = border; y < gray.rows - border; ++y)
    for (int x = border; x < gray.cols - border; ++x) {
      const float e = eig.at<float>(y, x);
      if (e > least && e >= most.at<float>(y, x)) peaks[{x, y}] = e;
    }
  return peaks;
}

cv::Mat Seafloor(int width, int height, uint32_t seed) {
  cv::Mat image = test::MakeImage(width, height, 1, 8, seed);
  // Some flat, saturated ground too: ties and zero responses.
  image(cv::Rect(width / 8, height / 8, width / 6, height / 6)).setTo(255);
  return image;
}

TEST(CornerPeaks, AreOpenCvsCornerMinEigenValPeaks) {
  for (const auto& [size, border] : {std::pair{cv::Size(640, 480), 11}, {cv::Size(333, 257), 3}, {cv::Size(96, 80), 3}}) {
    const cv::Mat gray = Seafloor(size.width, size.height, 7 + uint32_t(size.width));
    const auto theirs = OpenCvsPeaks(gray, border, 1e-7f);
    const std::vector<CornerPeak> ours = CornerPeaks(gray, border, 1e-7f);
    ASSERT_GT(theirs.size(), 50u) << size;
    // The responses are OpenCV's up to rounding; a peak may differ only where two neighbours tie
    // within that rounding.
    size_t same = 0;
    int previous = -1;
    for (const auto& p : ours) {
      EXPECT_GE(p.x, border);
      EXPECT_LT(p.x, size.width - border);
      EXPECT_GE(p.y, border);
      EXPECT_LT(p.y, size.height - border);
      EXPECT_GT(p.y * size.width + p.x, previous) << "raster order";
      previous = p.y * size.width + p.x;
      const auto it = theirs.find({p.x, p.y});
      if (it == theirs.end()) continue;
      ++same;
      EXPECT_NEAR(p.response, it->second, 1e-5 * it->second + 1e-9) << p.x << "," << p.y;
    }
    EXPECT_GE(double(same), 0.995 * double(theirs.size())) << size;
    EXPECT_GE(double(same), 0.995 * double(ours.size())) << size;
  }
}

TEST(CornerPeaks, ScalarIsTheVectorPathToTheBit) {
  const cv::Mat gray = Seafloor(517, 389, 3);
  const auto a = CornerPeaks(gray, 5, 1e-7f);
  const auto b = internal::CornerPeaksScalar(gray, 5, 1e-7f);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].x, b[i].x);
    EXPECT_EQ(a[i].y, b[i].y);
    EXPECT_EQ(a[i].response, b[i].response);
  }
}

TEST(CornerPeaks, LeastAndBorderAreHonoured) {
  const cv::Mat gray = Seafloor(200, 150, 11);
  const auto all = CornerPeaks(gray, 4, 1e-7f);
  ASSERT_FALSE(all.empty());
  float strongest = 0;
  for (const auto& p : all) strongest = std::max(strongest, p.response);
  const float least = 0.5f * strongest;
  for (const auto& p : CornerPeaks(gray, 4, least)) EXPECT_GT(p.response, least);
  // A flat image has no corners; one no larger than twice the border has no interior.
  EXPECT_TRUE(CornerPeaks(cv::Mat(100, 100, CV_8U, cv::Scalar(90)), 4, 1e-7f).empty());
  EXPECT_TRUE(CornerPeaks(gray(cv::Rect(0, 0, 8, 8)).clone(), 4, 1e-7f).empty());
}

TEST(CornerPeaks, RefusesWhatItCannotRead) {
  EXPECT_ANY_THROW(CornerPeaks(cv::Mat(50, 50, CV_32F, cv::Scalar(0)), 4, 1e-7f));
  EXPECT_ANY_THROW(CornerPeaks(cv::Mat(50, 50, CV_8U, cv::Scalar(0)), 2, 1e-7f));
}

}  // namespace
}  // namespace rolamos
