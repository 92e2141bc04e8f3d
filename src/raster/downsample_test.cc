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

}  // namespace
}  // namespace rolamos
