#include "synth/camera_path.h"

#include <gtest/gtest.h>

#include <cmath>

namespace rolamos {
namespace {

double YawStep(const CameraPose& a, const CameraPose& b) {
  return std::abs(std::remainder(b.yaw - a.yaw, 2 * CV_PI));
}

// The inspection path holds what an ROV pilot does that lanes and walks do not: frames that
// stay put, turns without moving, and motion far slower than the transit.
TEST(CameraPath, InspectionHoldsYawsInPlaceAndCreeps) {
  SurveyOptions o;
  o.path = "inspect";
  o.frames = 300;
  o.max_turn_deg = 4;
  o.forward_overlap = 0.95;
  const std::vector<CameraPose> poses = PlanCameraPath(o, cv::Rect2d(0, 0, 20000, 20000));
  ASSERT_EQ(poses.size(), 300u);
  const double step = o.frame_height * o.gsd * (1 - o.forward_overlap);
  int held = 0, yawed_in_place = 0, crept = 0, transit = 0;
  for (size_t i = 1; i < poses.size(); ++i) {
    const double moved = std::hypot(poses[i].position[0] - poses[i - 1].position[0],
                                    poses[i].position[1] - poses[i - 1].position[1]);
    const double turned = YawStep(poses[i - 1], poses[i]);
    EXPECT_LE(turned, o.max_turn_deg * CV_PI / 180 + 1e-9) << "frame " << i;
    if (moved < 0.1 * step && turned > 0.5 * o.max_turn_deg * CV_PI / 180) ++yawed_in_place;
    else if (moved < 0.1 * step) ++held;
    else if (moved < 0.2 * step) ++crept;
    else if (std::abs(moved - step) < 1e-6) ++transit;
  }
  EXPECT_GE(held, 30);
  EXPECT_GE(yawed_in_place, 30);
  EXPECT_GE(crept, 25);
  EXPECT_GE(transit, 70);
}

}  // namespace
}  // namespace rolamos
