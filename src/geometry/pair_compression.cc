#include "geometry/pair_compression.h"

#include <algorithm>
#include <cmath>

#include <opencv2/calib3d.hpp>

#include "util/homography.h"

namespace rolamos {
namespace {

// Points moved to their centroid and scaled to a mean distance of sqrt(2) (Hartley's
// normalisation, for a well-conditioned linear fit).
cv::Matx33d Normaliser(const std::vector<cv::Point2f>& p) {
  cv::Point2d mean;
  for (const auto& q : p) mean += cv::Point2d(q);
  mean *= 1.0 / double(p.size());
  double spread = 0;
  for (const auto& q : p) spread += cv::norm(cv::Point2d(q) - mean);
  const double s = std::sqrt(2.0) * double(p.size()) / std::max(spread, 1e-9);
  return cv::Matx33d(s, 0, -s * mean.x, 0, s, -s * mean.y, 0, 0, 1);
}

// The homography by the direct linear transformation, each pair's equations weighted.
bool WeightedDlt(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b, const std::vector<double>& weight,
                 cv::Matx33d* H) {
  const cv::Matx33d Ta = Normaliser(a), Tb = Normaliser(b);
  cv::Mat A(int(2 * a.size()), 9, CV_64F);
  for (size_t i = 0; i < a.size(); ++i) {
    const cv::Point2d p = ApplyHomography(Ta, a[i]), q = ApplyHomography(Tb, b[i]);
    const double w = std::sqrt(weight[i]);
    const double rows[2][9] = {{-p.x, -p.y, -1, 0, 0, 0, q.x * p.x, q.x * p.y, q.x},
                               {0, 0, 0, -p.x, -p.y, -1, q.y * p.x, q.y * p.y, q.y}};
    for (int r = 0; r < 2; ++r)
      for (int k = 0; k < 9; ++k) A.at<double>(int(2 * i) + r, k) = w * rows[r][k];
  }
  cv::Mat values, vt;
  cv::SVD::compute(A, values, cv::noArray(), vt, cv::SVD::MODIFY_A);
  cv::Matx33d Hn;
  for (int k = 0; k < 9; ++k) Hn(k / 3, k % 3) = vt.at<double>(vt.rows - 1, k);
  const cv::Matx33d out = Tb.inv() * Hn * Ta;
  if (!(std::abs(out(2, 2)) > 1e-12)) return false;
  *H = out * (1.0 / out(2, 2));
  return true;
}

// From the least-squares fit, each pair weighted 1 / (1 + (r / loss_px)^2) by its residual r, a
// few rounds.
cv::Matx33d CauchyFit(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b, cv::Matx33d H,
                      double loss_px) {
  constexpr int kRounds = 5;
  std::vector<double> weight(a.size());
  for (int round = 0; round < kRounds; ++round) {
    for (size_t i = 0; i < a.size(); ++i) {
      const double r = cv::norm(ApplyHomography(H, a[i]) - cv::Point2d(b[i])) / loss_px;
      weight[i] = 1.0 / (1.0 + r * r);
    }
    if (!WeightedDlt(a, b, weight, &H)) break;
  }
  return H;
}

}  // namespace

bool CompressPairs(const std::vector<cv::Point2f>& in_a, const std::vector<cv::Point2f>& in_b, int points,
                   CompressedPairs* out, double loss_px) {
  const size_t n = in_a.size();
  const int side = static_cast<int>(std::floor(std::sqrt(std::max(0, points))));
  if (side < 2 || n < 8 || n != in_b.size() || n <= size_t(side * side)) return false;
  const cv::Mat fit = cv::findHomography(in_a, in_b, 0);  // least squares, refined (LM)
  if (fit.empty()) return false;
  const cv::Matx33d H = loss_px > 0 ? CauchyFit(in_a, in_b, cv::Matx33d(fit), loss_px) : cv::Matx33d(fit);
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
