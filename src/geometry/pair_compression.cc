#include "geometry/pair_compression.h"

#include <algorithm>
#include <cmath>

#include <opencv2/calib3d.hpp>

#include "util/homography.h"

namespace rolamos {

bool CompressPairs(const std::vector<cv::Point2f>& in_a, const std::vector<cv::Point2f>& in_b, int points,
                   CompressedPairs* out) {
  const size_t n = in_a.size();
  const int side = static_cast<int>(std::floor(std::sqrt(std::max(0, points))));
  if (side < 2 || n < 8 || n != in_b.size() || n <= size_t(side * side)) return false;
  const cv::Mat fit = cv::findHomography(in_a, in_b, 0);  // least squares, refined (LM)
  if (fit.empty()) return false;
  const cv::Matx33d H(fit);
  // The pairs by cell of a side x side grid over their bounds.
  float x0 = in_a[0].x, x1 = x0, y0 = in_a[0].y, y1 = y0;
  for (const auto& p : in_a) x0 = std::min(x0, p.x), x1 = std::max(x1, p.x), y0 = std::min(y0, p.y), y1 = std::max(y1, p.y);
  const float w = std::max(1e-3f, x1 - x0), h = std::max(1e-3f, y1 - y0);
  std::vector<cv::Point2d> sum(size_t(side * side));
  std::vector<int> count(size_t(side * side), 0);
  cv::Point2d mean;
  double scatter = 0;
  for (size_t i = 0; i < n; ++i) {
    const cv::Point2f& p = in_a[i];
    const int cx = std::clamp(int((p.x - x0) * side / w), 0, side - 1);
    const int cy = std::clamp(int((p.y - y0) * side / h), 0, side - 1);
    sum[size_t(cy * side + cx)] += cv::Point2d(p);
    ++count[size_t(cy * side + cx)];
    mean += cv::Point2d(p);
    const cv::Point2d d = ApplyHomography(H, p) - cv::Point2d(in_b[i]);
    scatter += d.dot(d);
  }
  mean *= 1.0 / double(n);
  cv::Point2d total, between;
  for (const auto& p : in_a) total += cv::Point2d(std::pow(p.x - mean.x, 2), std::pow(p.y - mean.y, 2));
  std::vector<cv::Point2d> centre;
  std::vector<float> weight;
  for (size_t c = 0; c < count.size(); ++c) {
    if (count[c] == 0) continue;
    centre.push_back(sum[c] * (1.0 / count[c]));
    weight.push_back(std::sqrt(float(count[c])));
    between += count[c] * cv::Point2d(std::pow(centre.back().x - mean.x, 2), std::pow(centre.back().y - mean.y, 2));
  }
  if (centre.size() < 5) return false;
  const double sx = between.x > 0 ? std::clamp(std::sqrt(total.x / between.x), 1.0, 2.0) : 1.0;
  const double sy = between.y > 0 ? std::clamp(std::sqrt(total.y / between.y), 1.0, 2.0) : 1.0;
  CompressedPairs c;
  for (const auto& m : centre) {
    const cv::Point2d p(mean.x + (m.x - mean.x) * sx, mean.y + (m.y - mean.y) * sy);
    c.in_a.emplace_back(p);
    c.in_b.emplace_back(ApplyHomography(H, p));
  }
  c.weight = std::move(weight);
  c.scatter_px = std::sqrt(scatter / double(n));
  c.pairs = static_cast<int>(n);
  *out = std::move(c);
  return true;
}

}  // namespace rolamos
