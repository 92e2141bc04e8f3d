#include "engine/channel_shuffle.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "rolamos/error.hpp"

namespace rolamos {
namespace {

cv::Mat Noise(cv::Size size, int type, int seed) {
  cv::Mat m(size, type);
  cv::RNG rng(static_cast<uint64_t>(seed));
  rng.fill(m, cv::RNG::UNIFORM, 0, 256);
  return m;
}

// Widths of whole 64-pixel steps, with a tail, and narrower than one step; a view into a
// larger image each way.
TEST(ChannelShuffle, SplitIsCvSplit) {
  for (int width : {128, 203, 37}) {
    const cv::Mat bgr = Noise({width, 9}, CV_8UC3, width);
    cv::Mat ours[3], theirs[3];
    SplitBgr(bgr, ours);
    cv::split(bgr, theirs);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(cv::norm(ours[k], theirs[k], cv::NORM_INF), 0) << width << " wide, channel " << k;
  }
  const cv::Mat big = Noise({150, 20}, CV_8UC3, 1);
  cv::Mat padded[3], views[3], theirs[3];
  for (int k = 0; k < 3; ++k) {
    padded[k] = cv::Mat(24, 160, CV_8U, cv::Scalar(7));
    views[k] = padded[k](cv::Rect(2, 2, 140, 18));
  }
  SplitBgr(big(cv::Rect(5, 1, 140, 18)), views);
  cv::split(big(cv::Rect(5, 1, 140, 18)), theirs);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(views[k].data, padded[k].ptr(2) + 2);  // written in place
    EXPECT_EQ(cv::norm(views[k], theirs[k], cv::NORM_INF), 0);
    EXPECT_EQ(padded[k].at<uchar>(0, 0), 7);  // nothing outside the view
  }
}

TEST(ChannelShuffle, InterleaveIsMixChannels) {
  for (int width : {128, 203, 37}) {
    const cv::Mat bgr = Noise({width, 7}, CV_8UC3, width), code = Noise({width, 7}, CV_8UC1, width + 1);
    cv::Mat theirs(bgr.size(), CV_8UC4);
    const cv::Mat in[] = {bgr, code};
    const int from_to[] = {0, 0, 1, 1, 2, 2, 3, 3};
    cv::mixChannels(in, 2, &theirs, 1, from_to, 4);
    EXPECT_EQ(cv::norm(InterleaveBgrAnd(bgr, code), theirs, cv::NORM_INF), 0) << width << " wide";
  }
}

TEST(ChannelShuffle, SaysWhatItCannotShuffle) {
  cv::Mat planes[3];
  EXPECT_THROW(SplitBgr(cv::Mat(4, 4, CV_8UC4), planes), Error);
  EXPECT_THROW(InterleaveBgrAnd(cv::Mat(4, 4, CV_8UC3), cv::Mat(4, 5, CV_8UC1)), Error);
}

}  // namespace
}  // namespace rolamos
