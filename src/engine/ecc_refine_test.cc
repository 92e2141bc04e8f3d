#include "engine/ecc_refine.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "engine/feather.h"
#include "engine/patch_canvas.h"
#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

double CornerError(const cv::Matx33d& a, const cv::Matx33d& b, cv::Size s) {
  double worst = 0;
  for (cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(s.width - 1, 0), cv::Point2d(0, s.height - 1),
                        cv::Point2d(s.width - 1, s.height - 1)}) {
    cv::Vec3d u = a * cv::Vec3d(p.x, p.y, 1), v = b * cv::Vec3d(p.x, p.y, 1);
    worst = std::max(worst, std::hypot(u[0] / u[2] - v[0] / v[2], u[1] / u[2] - v[1] / v[2]));
  }
  return worst;
}

// A mosaic holding one frame at identity; a second frame is a known shift of the same ground.
// ECC must move a slightly wrong estimate onto the true placement.
TEST(Ecc, RecoversAKnownPlacementToSubPixel) {
  const cv::Size size(640, 480);
  cv::Mat ground = RenderSeafloor(0, 0, 900, 700);
  cv::Mat first = ground(cv::Rect(0, 0, 640, 480)).clone();
  PatchCanvas canvas(10'000'000);
  canvas.Add(first, FeatherCode(FeatherWeights(size, 0.2)), cv::Matx33d::eye());
  const cv::Matx33d truth(0.97, 0.05, 37.25, -0.04, 1.01, 21.5, 2e-5, -3e-5, 1);  // second frame -> patch
  cv::Mat second;
  cv::warpPerspective(ground, second, cv::Mat(truth), size, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
  cv::Mat gray;
  cv::cvtColor(second, gray, cv::COLOR_BGR2GRAY);
  const cv::Matx33d guess(0.972, 0.051, 38.5, -0.041, 1.009, 20.4, 2e-5, -3e-5, 1);
  EccResult r = RefineWithEcc(gray, guess, canvas, EccOptions{});
  ASSERT_TRUE(r.applied) << "correlation " << r.correlation;
  EXPECT_GT(r.correlation, 0.9);
  EXPECT_LT(CornerError(r.frame_to_patch, truth, size), 0.25);
  EXPECT_GT(CornerError(guess, truth, size), 1.0);
}

}  // namespace
}  // namespace rolamos
