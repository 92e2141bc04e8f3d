#include "engine/perspective_warp.h"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

cv::Mat Texture(cv::Size size, int type, uint64_t seed) {
  cv::RNG rng(seed);
  cv::Mat noise(size, CV_MAKETYPE(CV_32F, CV_MAT_CN(type)));
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(noise, noise, cv::Size(), 1.0);
  cv::Mat out;
  noise.convertTo(out, type);
  return out;
}

// A turn about the image centre, a scale, a shift and some perspective, as frames see it.
cv::Matx33d Homography(cv::Size size, cv::RNG& rng) {
  const double a = rng.uniform(-3.2, 3.2), s = rng.uniform(0.7, 1.4);
  const double cx = size.width / 2.0, cy = size.height / 2.0;
  const cv::Matx33d centre(1, 0, -cx, 0, 1, -cy, 0, 0, 1), back(1, 0, cx, 0, 1, cy, 0, 0, 1);
  const cv::Matx33d turn(s * std::cos(a), -s * std::sin(a), rng.uniform(-40.0, 40.0), s * std::sin(a),
                         s * std::cos(a), rng.uniform(-40.0, 40.0), rng.uniform(-4e-4, 4e-4), rng.uniform(-4e-4, 4e-4), 1);
  return back * turn * centre;
}

int Differing(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return -1;
  cv::Mat diff;
  cv::compare(a.reshape(1), b.reshape(1), diff, cv::CMP_NE);
  return cv::countNonZero(diff);
}

// OpenCV's pixels to the bit: each pixel's source rounded to 1/32 pixel from its block's first
// in OpenCV's order, its weights, its borders; on sizes whose blocks are narrower than 64 (few
// rows), odd widths, both directions of the map and every border handled.
TEST(PerspectiveWarp, GivesOpenCvsPixels) {
  cv::RNG rng(11);
  const cv::Size sizes[] = {{400, 300}, {333, 251}, {97, 9}, {5, 3}, {64, 17}};
  int pixels = 0;
  for (int type : {CV_8UC1, CV_8UC4})
    for (const cv::Size& size : sizes)
      for (int border : {cv::BORDER_REPLICATE, cv::BORDER_REFLECT, cv::BORDER_REFLECT_101})
        for (int flags : {int(cv::INTER_LINEAR), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP})
          for (int k = 0; k < 3; ++k) {
            const cv::Mat src = Texture(size, type, uint64_t(rng.next()));
            const cv::Matx33d H = Homography(size, rng);
            const cv::Size out_size(size.width + int(rng.uniform(-2, 30)), size.height + int(rng.uniform(-2, 30)));
            cv::Mat ours, theirs;
            WarpPerspectiveLinear(src, ours, H, out_size, flags, border);
            cv::warpPerspective(src, theirs, cv::Mat(H), out_size, flags, border);
            ASSERT_EQ(Differing(ours, theirs), 0)
                << cv::typeToString(type) << " " << size << " border " << border << " flags " << flags;
            pixels += int(theirs.total());
          }
  EXPECT_GT(pixels, 2000000);
}

// Float images with a border of zeros (ECC's view of the working canvas: its sums of colour and
// of weight) to the bit: OpenCV's float weights and order of sums, taps outside counted as 0.
TEST(PerspectiveWarp, GivesOpenCvsFloatPixels) {
  cv::RNG rng(17);
  int pixels = 0;
  for (int type : {CV_32FC1, CV_32FC3})
    for (const cv::Size& size : {cv::Size(323, 241), cv::Size(80, 61), cv::Size(7, 5)})
      for (int flags : {int(cv::INTER_LINEAR), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP})
        for (int k = 0; k < 4; ++k) {
          cv::Mat src(size, type);
          rng.fill(src, cv::RNG::UNIFORM, 0.0, 4000.0);
          const cv::Matx33d H = Homography(size, rng);
          const cv::Size out_size(size.width + int(rng.uniform(-3, 20)), size.height + int(rng.uniform(-3, 20)));
          cv::Mat ours, theirs;
          WarpPerspectiveLinear(src, ours, H, out_size, flags, cv::BORDER_CONSTANT);
          cv::warpPerspective(src, theirs, cv::Mat(H), out_size, flags, cv::BORDER_CONSTANT);
          ASSERT_EQ(Differing(ours, theirs), 0) << cv::typeToString(type) << " " << size << " flags " << flags;
          pixels += int(theirs.total());
        }
  EXPECT_GT(pixels, 300000);
}

// What is not handled here (another depth, a constant border) is OpenCV's own call.
TEST(PerspectiveWarp, OtherImagesGoToOpenCv) {
  cv::RNG rng(5);
  const cv::Mat grey16 = Texture({120, 90}, CV_16UC1, 3), colour = Texture({120, 90}, CV_8UC3, 4);
  const cv::Matx33d H = Homography({120, 90}, rng);
  for (const cv::Mat& src : {grey16, colour}) {
    cv::Mat ours, theirs;
    WarpPerspectiveLinear(src, ours, H, src.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::warpPerspective(src, theirs, cv::Mat(H), src.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    EXPECT_EQ(Differing(ours, theirs), 0);
  }
}

}  // namespace
}  // namespace rolamos
