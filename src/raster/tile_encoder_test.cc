#include "raster/tile_encoder.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

// A tile cut from a band as the file holds it: OpenCV's channel order change, edge pixels
// repeated out to a whole tile; a whole tile, one cut at the band's right end, and a narrow band.
TEST(CutFileTile, IsOpenCvsChannelOrderPaddedWithEdges) {
  cv::Mat band(40, 83, CV_8UC4);
  cv::RNG rng(3);
  rng.fill(band, cv::RNG::UNIFORM, 0, 256);
  const int tile_size = 32;
  for (int tx : {0, 1, 2}) {
    const int x0 = tx * tile_size, w = std::min(tile_size, band.cols - x0), h = std::min(tile_size, band.rows);
    cv::Mat rgba, expected;
    cv::cvtColor(band(cv::Rect(x0, 0, w, h)), rgba, cv::COLOR_BGRA2RGBA);
    cv::copyMakeBorder(rgba, expected, 0, tile_size - h, 0, tile_size - w, cv::BORDER_REPLICATE);
    const cv::Mat tile = CutFileTile(band, tx, tile_size);
    ASSERT_EQ(tile.size(), cv::Size(tile_size, tile_size));
    EXPECT_EQ(cv::norm(tile, expected, cv::NORM_INF), 0) << "tile " << tx;
  }
  const cv::Mat narrow = band(cv::Rect(0, 0, 5, 3)).clone();
  cv::Mat rgba, expected;
  cv::cvtColor(narrow, rgba, cv::COLOR_BGRA2RGBA);
  cv::copyMakeBorder(rgba, expected, 0, 8 - 3, 0, 8 - 5, cv::BORDER_REPLICATE);
  EXPECT_EQ(cv::norm(CutFileTile(narrow, 0, 8), expected, cv::NORM_INF), 0);
}

}  // namespace
}  // namespace rolamos
