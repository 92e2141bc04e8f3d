#include "engine/sift_detector.h"
#include "engine/sift_pyramid.h"

#include <cmath>
#include <cstdio>
#include <map>
#include <tuple>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "test_support.h"

#include "rolamos/error.hpp"

namespace rolamos {
namespace {

// The procedural seafloor, grey, a texture of its own for each seed.
cv::Mat Texture(cv::Size size, int seed) { return test::MakeImage(size.width, size.height, 1, 8, static_cast<uint32_t>(seed)); }

struct Agreement {
  size_t theirs = 0, ours = 0, same = 0;  // keypoints, and those in both
  double worst_descriptor = 0;            // largest distance between the two descriptors of one
};

// OpenCV's keypoints and ours paired by octave, layer and position (to 1e-3 px), size and angle.
Agreement Compare(const std::vector<cv::KeyPoint>& theirs, const cv::Mat& theirs_d, const std::vector<cv::KeyPoint>& ours,
                  const cv::Mat& ours_d) {
  Agreement a;
  a.theirs = theirs.size();
  a.ours = ours.size();
  std::multimap<std::tuple<int, long, long>, size_t> index;
  for (size_t i = 0; i < ours.size(); ++i)
    index.emplace(std::make_tuple(ours[i].octave & 0xFFFF, std::lround(ours[i].pt.x * 100), std::lround(ours[i].pt.y * 100)), i);
  for (size_t i = 0; i < theirs.size(); ++i) {
    const auto& t = theirs[i];
    const auto range = index.equal_range(std::make_tuple(t.octave & 0xFFFF, std::lround(t.pt.x * 100), std::lround(t.pt.y * 100)));
    for (auto it = range.first; it != range.second; ++it) {
      const auto& o = ours[it->second];
      if (std::abs(o.pt.x - t.pt.x) > 1e-3 || std::abs(o.pt.y - t.pt.y) > 1e-3 || std::abs(o.size - t.size) > 1e-3 * t.size ||
          std::abs(o.angle - t.angle) > 1e-2)
        continue;
      ++a.same;
      a.worst_descriptor = std::max(a.worst_descriptor, cv::norm(theirs_d.row(int(i)), ours_d.row(int(it->second))));
      break;
    }
  }
  return a;
}

TEST(SiftDetector, FindsAndDescribesWhatOpenCvsSiftDoes) {
  if (!FastSiftApplies()) GTEST_SKIP() << "no AVX-512 here: FindSift is cv::SIFT itself";
  int case_index = 0;
  for (const cv::Size size : {cv::Size(463, 345), cv::Size(320, 240), cv::Size(200, 150)})
    for (const double contrast : {0.005, 0.03}) {
      const cv::Mat image = Texture(size, size.width + case_index++);
      std::vector<cv::KeyPoint> theirs;
      cv::Mat theirs_d, ours_d;
      cv::SIFT::create(1000, 3, contrast)->detectAndCompute(image, cv::noArray(), theirs, theirs_d);
      SiftOptions options;
      options.contrast_threshold = contrast;
      const std::vector<cv::KeyPoint> ours = FindSift(image, cv::Mat(), options, &ours_d);
      ASSERT_EQ(ours_d.rows, static_cast<int>(ours.size()));
      ASSERT_GT(theirs.size(), 100u);
      const Agreement a = Compare(theirs, theirs_d, ours, ours_d);
      std::printf("%d x %d, contrast %.3f: OpenCV %zu keypoints, ours %zu, %zu the same; descriptors at most %.2f apart\n",
                  size.width, size.height, contrast, a.theirs, a.ours, a.same, a.worst_descriptor);
      // Float rounding may tip a candidate on a threshold's edge, or the thousandth strongest.
      EXPECT_GE(a.same, a.theirs * 99 / 100);
      EXPECT_LE(std::abs(double(a.ours) - double(a.theirs)), 0.01 * a.theirs + 2);
      EXPECT_LE(a.worst_descriptor, 6);
    }
}

TEST(SiftDetector, LeavesOutTheMaskedPixels) {
  const cv::Mat image = Texture({320, 240}, 9);
  cv::Mat mask(image.size(), CV_8U, cv::Scalar(255));
  mask(cv::Rect(0, 0, 160, 240)).setTo(0);
  cv::Mat d;
  const auto found = FindSift(image, mask, SiftOptions(), &d);
  ASSERT_FALSE(found.empty());
  for (const auto& k : found) EXPECT_GE(k.pt.x, 159.0f);
  // Without descriptors: the same keypoints.
  const auto alone = FindSift(image, mask, SiftOptions(), nullptr);
  ASSERT_EQ(alone.size(), found.size());
  for (size_t i = 0; i < found.size(); ++i) EXPECT_EQ(alone[i].pt, found[i].pt);
  std::vector<cv::KeyPoint> theirs;
  cv::Mat theirs_d;
  cv::SIFT::create(1000, 3, 0.04)->detectAndCompute(image, mask, theirs, theirs_d);
  EXPECT_LE(std::abs(double(found.size()) - double(theirs.size())), 0.01 * theirs.size() + 2);
}

TEST(SiftDetector, SaysWhatIsWrongWithItsInput) {
  cv::Mat d;
  EXPECT_THROW(FindSift(cv::Mat(40, 40, CV_8UC3), cv::Mat(), SiftOptions(), &d), Error);
  EXPECT_THROW(FindSift(Texture({40, 40}, 1), cv::Mat(20, 20, CV_8U), SiftOptions(), &d), Error);
  SiftOptions bad;
  bad.layers = 0;
  std::string why;
  EXPECT_FALSE(bad.IsValid(&why));
  EXPECT_THROW(FindSift(Texture({40, 40}, 1), cv::Mat(), bad, &d), Error);
}

}  // namespace
}  // namespace rolamos
