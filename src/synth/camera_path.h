// Camera trajectories over a rectangle of the texture: positions (x, y in texture pixels), yaw,
// and smooth altitude and tilt variations. Lane ends turn gradually, as vehicles do.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/survey.hpp"

namespace rolamos {

struct CameraPose {
  cv::Vec3d position;  // x, y on the texture; z = altitude above it (texture pixels)
  double yaw = 0, roll = 0, pitch = 0;  // radians
};

// `area` is the region of the texture the camera centre may visit.
std::vector<CameraPose> PlanCameraPath(const SurveyOptions& options, const cv::Rect2d& area);

// World plane (texture x, y, 1) -> frame pixel.
cv::Matx33d WorldToFrame(const CameraPose& pose, const cv::Matx33d& K);

}  // namespace rolamos
