#include "raster/mask_split.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

// The split as OpenCV's calls spell it: the specification the one-pass split keeps.
void SplitWithOpenCv(const cv::Mat& tile, cv::Mat* colour, cv::Mat* bits) {
  const int n = tile.channels() - 1;
  cv::Mat alpha;
  cv::extractChannel(tile, alpha, n);
  const cv::Mat data = alpha >= 128;
  colour->create(tile.size(), CV_8UC(n));
  const int from_to[] = {0, 0, 1, 1, 2, 2};
  cv::mixChannels(&tile, 1, colour, 1, from_to, size_t(n));
  const int with_data = cv::countNonZero(data);
  if (with_data > 0 && with_data < data.rows * data.cols) colour->setTo(cv::mean(*colour, data), ~data);
  bits->create(tile.rows, tile.cols / 8, CV_8UC1);
  for (int y = 0; y < tile.rows; ++y)
    for (int x = 0; x < tile.cols; x += 8) {
      uchar byte = 0;
      for (int k = 0; k < 8; ++k) byte = uchar(byte << 1) | uchar(data.at<uchar>(y, x + k) ? 1 : 0);
      bits->at<uchar>(y, x / 8) = byte;
    }
}

bool Same(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a.reshape(1) != b.reshape(1)) == 0;
}

// Tiles all data, none, a patch's edge (a disc), and scattered alpha, of RGBA and grey + alpha,
// with widths that leave a remainder past sixteen pixels.
TEST(MaskSplit, GivesWhatOpenCvsPassesGive) {
  cv::RNG rng(3);
  int partial = 0;
  for (int cn : {4, 2})
    for (cv::Size size : {cv::Size(256, 256), cv::Size(512, 64), cv::Size(40, 24), cv::Size(8, 3)})
      for (int kind = 0; kind < 4; ++kind) {
        cv::Mat tile(size, CV_8UC(cn));
        rng.fill(tile, cv::RNG::UNIFORM, 0, 256);
        std::vector<cv::Mat> planes;
        cv::split(tile, planes);
        cv::Mat& alpha = planes.back();
        if (kind == 0) alpha.setTo(255);
        if (kind == 1) alpha.setTo(0);
        if (kind == 2) {
          alpha.setTo(0);
          cv::circle(alpha, {size.width / 3, size.height / 2}, size.height / 2, 255, -1);
          alpha.at<uchar>(0, 0) = 128;  // the threshold itself is data
          alpha.at<uchar>(0, size.width - 1) = 127;
        }
        cv::merge(planes, tile);
        cv::Mat colour, bits, want_colour, want_bits;
        SplitMask(tile, &colour, &bits);
        SplitWithOpenCv(tile, &want_colour, &want_bits);
        EXPECT_TRUE(Same(colour, want_colour)) << cn << " " << size << " kind " << kind;
        EXPECT_TRUE(Same(bits, want_bits)) << cn << " " << size << " kind " << kind;
        const int data = cv::countNonZero(alpha >= 128);
        partial += data > 0 && data < int(alpha.total());
      }
  EXPECT_GE(partial, 12);  // the fill was exercised
}

}  // namespace
}  // namespace rolamos
