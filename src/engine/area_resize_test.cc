#include "engine/area_resize.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

int Differences(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return -1;
  const cv::Mat differ = a != b;
  return cv::countNonZero(differ.reshape(1));
}

// The engine's detection scales (a 1292 x 964 and an 800 x 600 frame down to 0.16 Mpx) and
// others, on noise and on seafloor, at odd sizes: cv::resize's pixels, every one.
TEST(ResizeArea, GivesCvResizesPixels) {
  const cv::Size sizes[] = {{1292, 964}, {800, 600}, {641, 479}, {97, 61}};
  const double scales[] = {std::sqrt(0.16e6 / (1292.0 * 964)), std::sqrt(0.16e6 / (800.0 * 600)), 0.3, 0.45, 0.7,
                           0.99, 0.26};
  int seed = 1;
  for (const cv::Size size : sizes) {
    const cv::Mat noise = test::MakeImage(size.width, size.height, 1, 8, seed++);
    cv::Mat ground = RenderSeafloor(seed * 13, seed * 7, size.width, size.height), grey;
    if (ground.channels() == 3) cv::cvtColor(ground, grey, cv::COLOR_BGR2GRAY);
    else grey = ground;
    const cv::Mat colour = test::MakeImage(size.width, size.height, 3, 8, seed++);
    for (double scale : scales) {
      for (const cv::Mat& src : {noise, grey, colour}) {
        cv::Mat ours, theirs;
        ResizeArea(src, ours, scale);
        cv::resize(src, theirs, cv::Size(), scale, scale, cv::INTER_AREA);
        EXPECT_EQ(Differences(ours, theirs), 0) << size << " at " << scale;
      }
    }
  }
}

// Whole factors (OpenCV's block average): an eighth (the exposure gains'), a quarter (the
// lighting model's), 3, and factors that differ each way; sizes the factor does not divide, so
// that blocks are cut at the right and bottom edges; by scale and by size.
TEST(ResizeArea, BlockAveragesAreCvResizes) {
  int seed = 5;
  for (const cv::Size size : {cv::Size(1292, 964), cv::Size(800, 600), cv::Size(101, 77), cv::Size(9, 5)})
    for (int channels : {1, 3, 4}) {
      const cv::Mat src = test::MakeImage(size.width, size.height, channels, 8, seed++);
      for (double scale : {0.125, 0.25, 1.0 / 3}) {
        cv::Mat ours, theirs;
        ResizeArea(src, ours, scale);
        cv::resize(src, theirs, cv::Size(), scale, scale, cv::INTER_AREA);
        EXPECT_EQ(Differences(ours, theirs), 0) << size << " x" << channels << " at " << scale;
      }
      for (const cv::Size factor : {cv::Size(4, 4), cv::Size(8, 3), cv::Size(1, 5), cv::Size(3, 3)}) {
        const cv::Size dsize(std::max(1, size.width / factor.width), std::max(1, size.height / factor.height));
        cv::Mat ours, theirs;
        ResizeArea(src, ours, dsize);
        cv::resize(src, theirs, dsize, 0, 0, cv::INTER_AREA);
        EXPECT_EQ(Differences(ours, theirs), 0) << size << " x" << channels << " to " << dsize;
      }
    }
}

// What it leaves to cv::resize gives cv::resize's result too: halving (a whole inverse), 16 bits,
// enlarging.
TEST(ResizeArea, OtherCasesAreCvResizes) {
  const cv::Mat grey = test::MakeImage(120, 90, 1, 8, 3), deep = test::MakeImage(120, 90, 3, 16, 4);
  for (const auto& [src, scale] : {std::pair{grey, 0.5}, std::pair{deep, 0.4}, std::pair{grey, 1.5}}) {
    cv::Mat ours, theirs;
    ResizeArea(src, ours, scale);
    cv::resize(src, theirs, cv::Size(), scale, scale, cv::INTER_AREA);
    ASSERT_EQ(ours.size(), theirs.size());
    EXPECT_EQ(cv::norm(ours, theirs, cv::NORM_INF), 0) << scale;
  }
}

}  // namespace
}  // namespace rolamos
