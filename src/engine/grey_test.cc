#include "engine/grey.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

// cv::cvtColor's bytes: noise (every value), whole and cut rows, a view into a larger image.
TEST(Grey, IsCvtColorsGrey) {
  cv::RNG rng(4);
  for (const cv::Size size : {cv::Size(1292, 964), cv::Size(801, 7), cv::Size(15, 3), cv::Size(1, 1)}) {
    cv::Mat bgr(size, CV_8UC3);
    rng.fill(bgr, cv::RNG::UNIFORM, 0, 256);
    cv::Mat ours, theirs;
    BgrToGrey(bgr, ours);
    cv::cvtColor(bgr, theirs, cv::COLOR_BGR2GRAY);
    ASSERT_EQ(ours.size(), theirs.size());
    EXPECT_EQ(cv::countNonZero(ours != theirs), 0) << size;
  }
  cv::Mat big(60, 90, CV_8UC3);
  rng.fill(big, cv::RNG::UNIFORM, 0, 256);
  const cv::Mat view = big(cv::Rect(3, 5, 70, 40));
  cv::Mat ours, theirs;
  BgrToGrey(view, ours);
  cv::cvtColor(view, theirs, cv::COLOR_BGR2GRAY);
  EXPECT_EQ(cv::countNonZero(ours != theirs), 0);
  // Other channels go to OpenCV.
  cv::Mat bgra(20, 30, CV_8UC4), grey4;
  rng.fill(bgra, cv::RNG::UNIFORM, 0, 256);
  BgrToGrey(bgra, ours);
  cv::cvtColor(bgra, grey4, cv::COLOR_BGRA2GRAY);
  EXPECT_EQ(cv::countNonZero(ours != grey4), 0);
}

}  // namespace
}  // namespace rolamos
