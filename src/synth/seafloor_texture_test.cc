#include "synth/seafloor_texture.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// The texture is a function of position: any window of it equals the same window cut from a
// larger render, also past OpenCV's 32767-pixel warp limit (rendered in pieces there).
TEST(SeafloorTexture, WindowsAgreeWithLargerRendersAndWideBandsWork) {
  const cv::Mat big = RenderSeafloor(1000, 2000, 600, 400);
  const cv::Mat part = RenderSeafloor(1100, 2050, 200, 100);
  EXPECT_LE(cv::norm(big(cv::Rect(100, 50, 200, 100)), part, cv::NORM_INF), 1.0);  // float rounding
  const cv::Mat wide = RenderSeafloor(0, 0, 40000, 8);
  ASSERT_EQ(wide.size(), cv::Size(40000, 8));
  const cv::Mat tail = RenderSeafloor(39000, 0, 1000, 8);
  EXPECT_LE(cv::norm(wide(cv::Rect(39000, 0, 1000, 8)), tail, cv::NORM_INF), 1.0);
}

}  // namespace
}  // namespace rolamos
