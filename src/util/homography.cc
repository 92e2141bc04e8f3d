#include "util/homography.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace rolamos {

cv::Matx33d ToMatx(const std::array<double, 9>& h) {
  cv::Matx33d m;
  for (int i = 0; i < 9; ++i) m.val[i] = h[static_cast<size_t>(i)];
  return m;
}

std::array<double, 9> ToArray9(const cv::Matx33d& m) {
  std::array<double, 9> h;
  for (int i = 0; i < 9; ++i) h[static_cast<size_t>(i)] = m.val[i] / m(2, 2);
  return h;
}

cv::Matx22d HomographyJacobian(const cv::Matx33d& H, cv::Point2d p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
  const double w = q[2], u = q[0] / w, v = q[1] / w;
  return cv::Matx22d((H(0, 0) - u * H(2, 0)) / w, (H(0, 1) - u * H(2, 1)) / w,
                     (H(1, 0) - v * H(2, 0)) / w, (H(1, 1) - v * H(2, 1)) / w);
}

double CentreScale(const cv::Matx33d& H, cv::Size size) {
  const double det = cv::determinant(HomographyJacobian(H, {(size.width - 1) / 2.0, (size.height - 1) / 2.0}));
  return std::sqrt(std::abs(det));
}

cv::Rect2d WarpedBounds(const cv::Matx33d& H, cv::Size size) {
  const cv::Point2d corners[] = {{-0.5, -0.5}, {size.width - 0.5, -0.5},
                                 {size.width - 0.5, size.height - 0.5}, {-0.5, size.height - 0.5}};
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const auto& c : corners) {
    const cv::Vec3d p = H * cv::Vec3d(c.x, c.y, 1);
    const double x = p[0] / p[2], y = p[1] / p[2];
    x0 = std::min(x0, x), y0 = std::min(y0, y), x1 = std::max(x1, x), y1 = std::max(y1, y);
  }
  return cv::Rect2d(x0, y0, x1 - x0, y1 - y0);
}

cv::Point2d ApplyHomography(const cv::Matx33d& H, cv::Point2d p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
  return {q[0] / q[2], q[1] / q[2]};
}

double MaxCornerShift(const cv::Matx33d& a, const cv::Matx33d& b, cv::Size size) {
  double worst = 0;
  for (const cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(size.width - 1.0, 0), cv::Point2d(0, size.height - 1.0),
                              cv::Point2d(size.width - 1.0, size.height - 1.0)})
    worst = std::max(worst, cv::norm(ApplyHomography(a, p) - ApplyHomography(b, p)));
  return worst;
}

cv::Matx33d BlendHomographies(const cv::Matx33d& a, const cv::Matx33d& b, double weight_a, cv::Size size) {
  const float w = static_cast<float>(size.width - 1), h = static_cast<float>(size.height - 1);
  const std::vector<cv::Point2f> corners{{0, 0}, {w, 0}, {w, h}, {0, h}};
  std::vector<cv::Point2f> between;
  for (const auto& c : corners) {
    const cv::Point2d p = weight_a * ApplyHomography(a, c) + (1 - weight_a) * ApplyHomography(b, c);
    between.emplace_back(static_cast<float>(p.x), static_cast<float>(p.y));
  }
  return cv::Matx33d(cv::getPerspectiveTransform(corners, between));
}

}  // namespace rolamos
