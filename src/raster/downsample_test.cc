#include "raster/downsample.h"

#include <gtest/gtest.h>

#include "test_support.h"

namespace rolamos {
namespace {

// An odd-sized view pairs its last row and column with themselves, never with the pixels that
// lie past it in the parent (the band writer's reused buffers once leaked stale rows in).
TEST(Downsample2x, AnOddViewIgnoresItsParent) {
  for (int channels : {3, 4}) {
    const cv::Mat parent = test::MakeImage(300, 200, channels, 8);
    const cv::Mat view = parent(cv::Rect(10, 20, 131, 97));
    cv::Mat d;
    cv::absdiff(Downsample2x(view, channels == 4), Downsample2x(view.clone(), channels == 4), d);
    EXPECT_EQ(cv::countNonZero(d.reshape(1)), 0) << channels << " channels";
  }
}

// Each 2 x 2 block's colour weighted by its alpha, rounded half up, by the book (64-bit integers).
cv::Mat Reference(const cv::Mat& src) {
  cv::Mat dst(src.rows / 2, src.cols / 2, src.type());
  for (int y = 0; y < dst.rows; ++y)
    for (int x = 0; x < dst.cols; ++x) {
      const cv::Vec4b p[4] = {src.at<cv::Vec4b>(2 * y, 2 * x), src.at<cv::Vec4b>(2 * y, 2 * x + 1),
                              src.at<cv::Vec4b>(2 * y + 1, 2 * x), src.at<cv::Vec4b>(2 * y + 1, 2 * x + 1)};
      const uint64_t a = uint64_t(p[0][3]) + p[1][3] + p[2][3] + p[3][3];
      cv::Vec4b& o = dst.at<cv::Vec4b>(y, x);
      for (int c = 0; c < 3; ++c) {
        uint64_t s = 0;
        for (const auto& q : p) s += uint64_t(q[c]) * q[3];
        o[c] = a ? uint8_t((s + a / 2) / a) : 0;
      }
      o[3] = uint8_t(a ? (a + 2) / 4 : 0);
    }
  return dst;
}

TEST(Downsample2x, AlphaWeightedIsExactOnEightBits) {
  cv::Mat src(1024, 2048, CV_8UC4);
  cv::RNG rng(17);
  rng.fill(src, cv::RNG::UNIFORM, 0, 256);
  // Alphas of every kind: the feathered edge's small ones, full, none.
  for (int y = 0; y < src.rows; ++y)
    for (int x = 0; x < src.cols; ++x) {
      uchar& a = src.at<cv::Vec4b>(y, x)[3];
      if ((x / 64 + y / 64) % 3 == 0) a = 255;
      else if ((x / 64 + y / 64) % 3 == 1) a = uchar(a % 8);
    }
  for (const cv::Rect& part : {cv::Rect(0, 0, 2048, 1024), cv::Rect(6, 2, 1030, 998)}) {  // and a tail of 3
    cv::Mat d;
    cv::absdiff(Downsample2x(src(part), true), Reference(src(part)), d);
    EXPECT_EQ(cv::countNonZero(d.reshape(1)), 0) << part;
  }
}

}  // namespace
}  // namespace rolamos
