#include "engine/sift_descriptor.h"
#include "engine/sift_pyramid.h"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

// The procedural seafloor, grey, a texture of its own for each seed.
cv::Mat Texture(cv::Size size, int seed) { return test::MakeImage(size.width, size.height, 1, 8, static_cast<uint32_t>(seed)); }

struct Agreement {
  double same = 0;       // fraction of entries equal
  double worst = 0;      // largest difference of an entry
  double worst_l2 = 0;   // largest distance between a keypoint's two descriptors
};

Agreement Compare(const cv::Mat& ours, const cv::Mat& theirs) {
  Agreement a;
  EXPECT_EQ(ours.size(), theirs.size());
  EXPECT_EQ(ours.type(), CV_32F);
  if (ours.size() != theirs.size() || ours.empty()) return a;
  cv::Mat diff;
  cv::absdiff(ours, theirs, diff);
  a.same = 1.0 - cv::countNonZero(diff) / double(diff.total());
  cv::minMaxLoc(diff, nullptr, &a.worst);
  for (int i = 0; i < ours.rows; ++i) a.worst_l2 = std::max(a.worst_l2, cv::norm(ours.row(i), theirs.row(i)));
  return a;
}

// What OpenCV's SIFT finds on `image` (first octave doubled, as the engine runs it), described
// by OpenCV and by DescribeSift.
TEST(SiftDescriptor, IsOpenCvsDescriptor) {
  if (!FastSiftApplies()) GTEST_SKIP() << "no AVX-512 here: DescribeSift is OpenCV's own";
  for (const cv::Size size : {cv::Size(463, 345), cv::Size(320, 240)}) {
    const cv::Mat image = Texture(size, size.width);
    auto sift = cv::SIFT::create(1000, 3, 0.005);
    std::vector<cv::KeyPoint> keypoints;
    cv::Mat theirs, ours;
    sift->detectAndCompute(image, cv::noArray(), keypoints, theirs);
    ASSERT_GT(keypoints.size(), 500u);
    DescribeSift(image, keypoints, 3, 1.6, &ours);
    const Agreement a = Compare(ours, theirs);
    std::printf("%d x %d: %zu keypoints, %.4f of entries equal, worst entry off by %.0f, worst distance %.2f\n",
                size.width, size.height, keypoints.size(), a.same, a.worst, a.worst_l2);
    // Float rounding tips an entry by one now and then; descriptors a match tells apart lie
    // hundreds apart.
    EXPECT_GE(a.same, 0.995);
    EXPECT_LE(a.worst, 2);
    EXPECT_LE(a.worst_l2, 4);
  }
}

// Keypoints of the octaves above the first, described on the image itself (no doubled octave), as
// cv::SIFT::compute describes them.
TEST(SiftDescriptor, DescribesWithoutTheDoubledOctave) {
  if (!FastSiftApplies()) GTEST_SKIP() << "no AVX-512 here: DescribeSift is OpenCV's own";
  const cv::Mat image = Texture({400, 300}, 5);
  auto sift = cv::SIFT::create(600, 3, 0.005);
  std::vector<cv::KeyPoint> keypoints;
  sift->detect(image, keypoints);
  std::vector<cv::KeyPoint> upper;
  for (const auto& k : keypoints)
    if ((k.octave & 255) != 255) upper.push_back(k);  // octave 0 and up
  ASSERT_GT(upper.size(), 50u);
  cv::Mat theirs, ours;
  std::vector<cv::KeyPoint> copy = upper;
  sift->compute(image, copy, theirs);
  ASSERT_EQ(copy.size(), upper.size());
  DescribeSift(image, upper, 3, 1.6, &ours);
  const Agreement a = Compare(ours, theirs);
  EXPECT_GE(a.same, 0.995);
  EXPECT_LE(a.worst_l2, 4);
}

TEST(SiftDescriptor, NoKeypointsNoRows) {
  cv::Mat d;
  DescribeSift(Texture({64, 48}, 1), {}, 3, 1.6, &d);
  EXPECT_EQ(d.rows, 0);
}

}  // namespace
}  // namespace rolamos
