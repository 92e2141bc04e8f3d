#include "util/exposure_gains.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "util/homography.h"

namespace rolamos {

std::vector<double> SolveExposureGains(const std::vector<cv::Mat>& images, double scale,
                                       const std::vector<cv::Matx33d>& placements, double prior) {
  const size_t n = images.size();
  std::vector<double> gains(n, 1.0);
  if (n < 2) return gains;
  // Each frame's brightness on the patch at the images' resolution, with where it is.
  const cv::Matx33d S(scale, 0, 0.5 * (scale - 1), 0, scale, 0.5 * (scale - 1), 0, 0, 1);
  struct Placed {
    cv::Rect box;
    cv::Mat lum, mask;
  };
  std::vector<Placed> placed(n);
  for (size_t k = 0; k < n; ++k) {
    cv::Mat gray, valid;
    if (images[k].channels() == 4) {  // alpha says where the image has data
      cv::extractChannel(images[k], valid, 3);
      valid = valid > 127;
      cv::cvtColor(images[k], gray, cv::COLOR_BGRA2GRAY);
    } else {
      cv::cvtColor(images[k], gray, cv::COLOR_BGR2GRAY);
      valid = cv::Mat(gray.size(), CV_8U, cv::Scalar(255));
    }
    gray.convertTo(gray, CV_32F);
    const cv::Matx33d H = S * placements[k] * S.inv();
    const cv::Rect2d b = WarpedBounds(H, gray.size());
    placed[k].box = cv::Rect(int(std::floor(b.x)), int(std::floor(b.y)), int(std::ceil(b.width)) + 1, int(std::ceil(b.height)) + 1);
    const cv::Matx33d T(1, 0, -placed[k].box.x, 0, 1, -placed[k].box.y, 0, 0, 1);
    cv::warpPerspective(gray, placed[k].lum, cv::Mat(T * H), placed[k].box.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::warpPerspective(valid, placed[k].mask, cv::Mat(T * H), placed[k].box.size(), cv::INTER_NEAREST, cv::BORDER_CONSTANT);
    cv::erode(placed[k].mask, placed[k].mask, cv::Mat());
  }
  // log g_k + log m_k(kj) = log g_j + log m_j(kj) for every overlapping pair, and the gains held
  // to their average.
  std::vector<std::array<double, 4>> eq;  // k, j, log(m_j / m_k), weight
  for (size_t k = 0; k < n; ++k)
    for (size_t j = k + 1; j < n; ++j) {
      const cv::Rect common = placed[k].box & placed[j].box;
      if (common.area() < 50) continue;
      const cv::Mat mk = placed[k].mask(common - placed[k].box.tl()), mj = placed[j].mask(common - placed[j].box.tl());
      const cv::Mat both = mk & mj;
      const int count = cv::countNonZero(both);
      if (count < 50) continue;
      const double lk = cv::mean(placed[k].lum(common - placed[k].box.tl()), both)[0];
      const double lj = cv::mean(placed[j].lum(common - placed[j].box.tl()), both)[0];
      if (!(lk > 1 && lj > 1)) continue;
      eq.push_back({double(k), double(j), std::log(lj / lk), std::sqrt(double(count))});
    }
  if (eq.empty()) return gains;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(Eigen::Index(eq.size() + n + 1), Eigen::Index(n));
  Eigen::VectorXd b = Eigen::VectorXd::Zero(A.rows());
  for (size_t r = 0; r < eq.size(); ++r) {
    const auto& [k, j, d, w] = eq[r];
    A(Eigen::Index(r), Eigen::Index(k)) = w;
    A(Eigen::Index(r), Eigen::Index(j)) = -w;
    b(Eigen::Index(r)) = w * d;
  }
  double wmean = 0;
  for (const auto& e : eq) wmean += e[3];
  wmean /= eq.size();
  for (size_t k = 0; k < n; ++k) A(Eigen::Index(eq.size() + k), Eigen::Index(k)) = prior * wmean;
  for (size_t k = 0; k < n; ++k) A(Eigen::Index(eq.size() + n), Eigen::Index(k)) = wmean;  // mean log gain 0
  const Eigen::VectorXd x = A.colPivHouseholderQr().solve(b);
  for (size_t k = 0; k < n; ++k) gains[k] = std::clamp(std::exp(x(Eigen::Index(k))), 0.5, 2.0);
  return gains;
}

}  // namespace rolamos
