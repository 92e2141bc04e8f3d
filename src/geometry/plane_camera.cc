#include "geometry/plane_camera.h"

#include <cmath>

namespace rolamos {

PlanePose PlanePose::FromArray(const std::array<double, 6>& a) {
  PlanePose p;
  p.yaw = a[0];
  p.pitch = a[1];
  p.roll = a[2];
  p.centre = cv::Vec3d(a[3], a[4], a[5]);
  return p;
}

cv::Matx33d CameraMatrix(double focal, cv::Size size) {
  return cv::Matx33d(focal, 0, (size.width - 1) / 2.0, 0, focal, (size.height - 1) / 2.0, 0, 0, 1);
}

cv::Matx33d WorldToCamera(const PlanePose& p) {
  const double cr = std::cos(p.roll), sr = std::sin(p.roll);
  const double cp = std::cos(p.pitch), sp = std::sin(p.pitch);
  const double cy = std::cos(p.yaw), sy = std::sin(p.yaw);
  const cv::Matx33d Rx(1, 0, 0, 0, cr, -sr, 0, sr, cr);
  const cv::Matx33d Ry(cp, 0, sp, 0, 1, 0, -sp, 0, cp);
  const cv::Matx33d Rz(cy, sy, 0, -sy, cy, 0, 0, 0, 1);
  return Rx * Ry * Rz;
}

cv::Matx33d PlaneToFrame(const PlanePose& pose, const cv::Matx33d& K) {
  const cv::Matx33d R = WorldToCamera(pose);
  const cv::Vec3d t = -(R * pose.centre);
  // Points (x, y, 0): columns r1, r2 and t.
  const cv::Matx33d M(R(0, 0), R(0, 1), t[0], R(1, 0), R(1, 1), t[1], R(2, 0), R(2, 1), t[2]);
  return K * M;
}

cv::Matx33d FrameToPlane(const PlanePose& pose, const cv::Matx33d& K) {
  cv::Matx33d H = PlaneToFrame(pose, K).inv();
  return H * (1.0 / H(2, 2));
}

PlanePose LevelPoseFromHomography(const cv::Matx33d& H, const cv::Matx33d& K, cv::Size size) {
  const double cx = (size.width - 1) / 2.0, cy = (size.height - 1) / 2.0;
  auto map = [&](double x, double y) {
    const cv::Vec3d q = H * cv::Vec3d(x, y, 1);
    return cv::Point2d(q[0] / q[2], q[1] / q[2]);
  };
  const cv::Point2d c = map(cx, cy), u = map(cx + 100, cy) - c;
  const double scale = std::hypot(u.x, u.y) / 100.0;  // map pixels per frame pixel
  PlanePose p;
  // A level camera with yaw y maps the frame's x axis to the map direction (cos y, sin y)
  // (the first row of the world->camera rotation Rz(y)): y is the angle of u.
  p.yaw = std::atan2(u.y, u.x);
  p.centre = cv::Vec3d(c.x, c.y, -K(0, 0) * scale);
  return p;
}

PlanePose ReferencePose(const cv::Matx33d& K) {
  PlanePose p;
  p.centre = cv::Vec3d(K(0, 2), K(1, 2), -K(0, 0));
  return p;
}

}  // namespace rolamos
