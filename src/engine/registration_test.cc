#include "engine/registration.h"

#include <cmath>

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// The homography between two views of a plane from one camera centre, the second pitched by
// `pitch_deg` and rolled by `roll_deg`: K R K^-1, K of a frame `fov_deg` across.
cv::Matx33d Turned(cv::Size frame, double fov_deg, double pitch_deg, double roll_deg) {
  const double f = 0.5 * frame.width / std::tan(0.5 * fov_deg * CV_PI / 180);
  const cv::Matx33d K(f, 0, (frame.width - 1) / 2.0, 0, f, (frame.height - 1) / 2.0, 0, 0, 1);
  const double p = pitch_deg * CV_PI / 180, r = roll_deg * CV_PI / 180;
  const cv::Matx33d pitch(1, 0, 0, 0, std::cos(p), -std::sin(p), 0, std::sin(p), std::cos(p));
  const cv::Matx33d roll(std::cos(r), 0, std::sin(r), 0, 1, 0, -std::sin(r), 0, std::cos(r));
  return K * pitch * roll * K.inv();
}

TEST(Registration, AttitudeChangesAVehicleMakesBetweenFramesArePlausible) {
  const cv::Size frame(1292, 964);
  const SupportOptions o;
  // A 1292 x 964 video at 90 degrees across, rolled and pitched by 2 degrees anew at every frame:
  // two frames in a row differ by up to 8 degrees (bench/RESULTS.md, session 21).
  for (double fov : {50.0, 70.0, 90.0}) {
    for (const cv::Vec2d& turn : {cv::Vec2d(2, 0), cv::Vec2d(5, 0), cv::Vec2d(8, 0), cv::Vec2d(-8, 0),
                                 cv::Vec2d(0, 8), cv::Vec2d(5, 5), cv::Vec2d(-5, 5)})
      EXPECT_TRUE(IsPlausibleMotion(Turned(frame, fov, turn[0], turn[1]), frame, o))
          << fov << " degrees across, pitched " << turn[0] << ", rolled " << turn[1];
  }
}

TEST(Registration, MirrorsFoldsAndWildPerspectiveAreNot) {
  const cv::Size frame(800, 600);
  const SupportOptions o;
  EXPECT_TRUE(IsPlausibleMotion(cv::Matx33d::eye(), frame, o));
  // A mirror image.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(-1, 0, 799, 0, 1, 0, 0, 0, 1), frame, o));
  // The horizon inside the frame: the plane folds over.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(1, 0, 0, 0, 1, 0, 0, -1.0 / 300, 1), frame, o));
  // Scale across the frame changing by half again or more: a camera turned 20 degrees at 90
  // across in 1/30 s, or (far likelier) a false registration.
  EXPECT_FALSE(IsPlausibleMotion(Turned(frame, 90, 20, 0), frame, o));
  // Too much zoom, too much shear.
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(2, 0, 0, 0, 2, 0, 0, 0, 1), frame, o));
  EXPECT_FALSE(IsPlausibleMotion(cv::Matx33d(1, 0.8, 0, 0, 1, 0, 0, 0, 1), frame, o));
}

}  // namespace
}  // namespace rolamos
