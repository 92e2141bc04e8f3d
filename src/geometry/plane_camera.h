// A downward camera over the seafloor plane: the model that keeps a map from bending.
//
// Chained frame-to-frame homographies accumulate the errors of their projective terms, which
// show as a bend that grows along a lane (1-3 px over 25 frames of 800 x 600 with 1 degree of
// roll and pitch jitter). Here each frame is a pose over one plane (z = 0): its roll and pitch are
// measured against the plane by every frame it overlaps, so they do not accumulate; only the
// similarity part (position, heading, altitude) drifts, and slowly.
//
// World: x right, y down (the map's pixel axes), z into the seafloor; the camera at centre C
// (C.z < 0: |C.z| is the altitude in map pixels) looks along +z when level. World-to-camera
// rotation R = Rx(roll) Ry(pitch) Rz(yaw), the convention of rolamos synth.
#pragma once

#include <array>
#include <cmath>

#include <opencv2/core.hpp>

namespace rolamos {

struct PlanePose {
  double yaw = 0, pitch = 0, roll = 0;  // radians
  cv::Vec3d centre{0, 0, -1};           // map pixels; z < 0
  std::array<double, 6> ToArray() const { return {yaw, pitch, roll, centre[0], centre[1], centre[2]}; }
  static PlanePose FromArray(const std::array<double, 6>& a);
};

// The pinhole camera of frames of `size` with focal length `focal` pixels, centred.
cv::Matx33d CameraMatrix(double focal, cv::Size size);

cv::Matx33d WorldToCamera(const PlanePose& pose);

// WorldToCamera's rotation from a pose's (yaw, pitch, roll), multiplied out for Ceres's jets
// (the plane adjustment's residuals): Rx(roll) * Ry(pitch) * Rz(yaw), row-major.
template <typename T>
void PlaneRotation(const T* e, T R[9]) {
  using std::cos;
  using std::sin;
  const T cy = cos(e[0]), sy = sin(e[0]), cp = cos(e[1]), sp = sin(e[1]), cr = cos(e[2]), sr = sin(e[2]);
  const T a[9] = {cp * cy, cp * sy, sp, -sy, cy, T(0), -sp * cy, -sp * sy, cp};  // Ry * Rz
  R[0] = a[0];
  R[1] = a[1];
  R[2] = a[2];
  R[3] = cr * a[3] - sr * a[6];
  R[4] = cr * a[4] - sr * a[7];
  R[5] = cr * a[5] - sr * a[8];
  R[6] = sr * a[3] + cr * a[6];
  R[7] = sr * a[4] + cr * a[7];
  R[8] = sr * a[5] + cr * a[8];
}

// Map (plane) pixel -> frame pixel, and back.
cv::Matx33d PlaneToFrame(const PlanePose& pose, const cv::Matx33d& K);
cv::Matx33d FrameToPlane(const PlanePose& pose, const cv::Matx33d& K);

// A level camera that puts the frame where `frame_to_plane` does at its centre (position,
// heading, scale): the starting point of an adjustment from homographies.
PlanePose LevelPoseFromHomography(const cv::Matx33d& frame_to_plane, const cv::Matx33d& K, cv::Size size);

// The reference camera of a new map: level, over map pixel (cx, cy) of its centre at the altitude
// that makes one map pixel one frame pixel.
PlanePose ReferencePose(const cv::Matx33d& K);

}  // namespace rolamos
