#include "engine/egomotion.h"

#include <algorithm>
#include <cmath>

#include <opencv2/calib3d.hpp>

namespace rolamos {

bool EgomotionOptions::IsValid(std::string* error) const {
  if (!(epipolar_threshold_px > 0 && homography_threshold_px > 0)) {
    *error = "RANSAC thresholds must be positive";
    return false;
  }
  if (min_inliers < 8 || min_few_inliers < 8 || min_few_inliers > min_inliers) {
    *error = "at least 8 inliers are needed for a homography (" + std::to_string(min_few_inliers) + " and " +
             std::to_string(min_inliers) + " asked), and no more for few matches than for many";
    return false;
  }
  return true;
}

int EgomotionOptions::RequiredInliers(int matches) const {
  return std::clamp(static_cast<int>(std::ceil(0.75 * matches)), min_few_inliers, min_inliers);
}

double BilateralEpipolarError(const cv::Matx33d& F, const cv::Point2f& p1, const cv::Point2f& p2) {
  const cv::Vec3d x1(p1.x, p1.y, 1), x2(p2.x, p2.y, 1);
  const cv::Vec3d l2 = F * x1;            // epipolar line of p1 in image 2
  const cv::Vec3d l1 = F.t() * x2;        // epipolar line of p2 in image 1
  const double d2 = std::abs(l2.dot(x2)) / std::max(1e-12, std::hypot(l2[0], l2[1]));
  const double d1 = std::abs(l1.dot(x1)) / std::max(1e-12, std::hypot(l1[0], l1[1]));
  return d1 + d2;
}

std::optional<PlaneMotion> DecomposeHomography(const cv::Matx33d& H, const cv::Matx33d& K,
                                               const std::vector<cv::Point2f>& from,
                                               const std::vector<cv::Point2f>& to) {
  std::vector<cv::Mat> rotations, translations, normals;
  const int n = cv::decomposeHomographyMat(cv::Mat(H), cv::Mat(K), rotations, translations, normals);
  if (n <= 0) return std::nullopt;
  // Positive depth: reference points must lie in front of both cameras (normalised coords).
  std::vector<cv::Point2f> a, b;
  const cv::Matx33d Kinv = K.inv();
  for (size_t i = 0; i < from.size(); ++i) {
    cv::Vec3d p = Kinv * cv::Vec3d(from[i].x, from[i].y, 1), q = Kinv * cv::Vec3d(to[i].x, to[i].y, 1);
    a.emplace_back(static_cast<float>(p[0] / p[2]), static_cast<float>(p[1] / p[2]));
    b.emplace_back(static_cast<float>(q[0] / q[2]), static_cast<float>(q[1] / q[2]));
  }
  std::vector<int> possible;
  cv::filterHomographyDecompByVisibleRefpoints(rotations, normals, a, b, possible);
  if (possible.empty()) return std::nullopt;
  int best = possible[0];
  double best_z = -1;
  for (int i : possible) {
    const double z = std::abs(normals[static_cast<size_t>(i)].at<double>(2));
    if (z > best_z) {
      best_z = z;
      best = i;
    }
  }
  PlaneMotion m;
  m.R = cv::Matx33d(rotations[static_cast<size_t>(best)]);
  m.t = cv::Vec3d(translations[static_cast<size_t>(best)]);
  m.n = cv::Vec3d(normals[static_cast<size_t>(best)]);
  return m;
}

EgomotionResult EstimateEgomotion(const std::vector<cv::Point2f>& from,
                                  const std::vector<cv::Point2f>& to, const cv::Matx33d& K,
                                  const EgomotionOptions& o) {
  EgomotionResult r;
  r.matches = static_cast<int>(from.size());
  const int required = o.RequiredInliers(r.matches);
  if (r.matches < required) {
    r.failure = "too_few_matches";
    return r;
  }
  std::vector<cv::Point2f> a = from, b = to;
  std::vector<int> index(from.size());  // of a[i] in `from`
  for (size_t i = 0; i < index.size(); ++i) index[i] = static_cast<int>(i);
  const std::vector<int> all = index;
  if (o.use_fundamental) {
    std::vector<uchar> mask;
    cv::Mat F = cv::findFundamentalMat(from, to, cv::USAC_MAGSAC, o.epipolar_threshold_px, 0.999,
                                       mask);
    if (F.rows == 3 && F.cols == 3) {
      const cv::Matx33d Fm(F);
      a.clear();
      b.clear();
      index.clear();
      for (size_t i = 0; i < from.size(); ++i) {
        const double e = BilateralEpipolarError(Fm, from[i], to[i]);
        if (e > 2.0 * o.epipolar_threshold_px) continue;  // each side within the threshold
        a.push_back(from[i]);
        b.push_back(to[i]);
        index.push_back(static_cast<int>(i));
        r.bilateral_error_sum += e;
      }
    }
    // A failed F (degenerate set) falls back to the homography's own RANSAC.
    r.epipolar_inliers = static_cast<int>(a.size());
    if (r.epipolar_inliers < required) {
      a = from;
      b = to;
      index = all;
      r.bilateral_error_sum = 0;
    }
  }
  if (static_cast<int>(a.size()) < required) {
    r.failure = "too_few_epipolar_inliers";
    return r;
  }
  std::vector<uchar> hmask;
  cv::Mat H = cv::findHomography(a, b, cv::USAC_MAGSAC, o.homography_threshold_px, hmask, 2000, 0.999);
  if (H.empty()) {
    r.failure = "homography_failed";
    return r;
  }
  std::vector<cv::Point2f> ia, ib;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!hmask[i]) continue;
    ia.push_back(a[i]);
    ib.push_back(b[i]);
    r.inlier_index.push_back(index[i]);
  }
  r.inliers = static_cast<int>(ia.size());
  if (r.inliers < required) {
    r.failure = "too_few_inliers";
    return r;
  }
  // Least-squares polish on all inliers (RANSAC's model comes from a minimal sample).
  cv::Mat refined = cv::findHomography(ia, ib, 0);
  if (!refined.empty()) H = refined;
  r.H = cv::Matx33d(H);
  r.H *= 1.0 / r.H(2, 2);
  if (r.epipolar_inliers > 0) r.bilateral_error_mean = r.bilateral_error_sum / r.epipolar_inliers;
  r.motion = DecomposeHomography(r.H, K, ia, ib);
  r.inlier_from = std::move(ia);
  r.inlier_to = std::move(ib);
  r.ok = true;
  return r;
}

}  // namespace rolamos
