// Stage 2b: egomotion between two frames from matched features, as in section 3.2 of the paper.
// 1. Fundamental matrix by RANSAC (OpenCV's USAC MAGSAC++); every match's bilateral epipolar
//    error (equation 1: distance of each point to the other's epipolar line, summed) drops
//    outliers and, summed over the survivors, is the quality figure.
// 2. Homography from the surviving matches (the seafloor is roughly flat).
// 3. Its decomposition into R, t, n (cv::decomposeHomographyMat); impossible solutions are removed
//    by the positive-depth constraint, and of the rest the plane facing the camera is kept.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct EgomotionOptions {
  double epipolar_threshold_px = 1.5;    // RANSAC threshold for F, and half the bilateral cut
  double homography_threshold_px = 3.0;  // RANSAC threshold for H
  int min_inliers = 25;
  // Fewer are enough where few features match at all (low-contrast ground under uneven light, a
  // small overlap) when nearly all of them agree, three in four, down to this many (skerki6's last
  // frame: 17 of 21 matches, placed where it belongs; 25 rejected it). Such a registration is weak
  // (SupportOptions): the Kalman gate must agree with it. Where more match, fewer agreeing still
  // is not enough (small-degraded: 24 of 39 on a frame full of marine snow).
  int min_few_inliers = 15;
  bool use_fundamental = true;  // the paper's outlier stage (off: H by RANSAC alone)

  bool IsValid(std::string* error) const;
  // Inliers needed among `matches` matched pairs.
  int RequiredInliers(int matches) const;
};

struct PlaneMotion {
  cv::Matx33d R = cv::Matx33d::eye();
  cv::Vec3d t, n;
};

struct EgomotionResult {
  bool ok = false;
  std::string failure;  // why not ok: "too_few_matches", "fundamental_failed", ...
  int matches = 0;
  int epipolar_inliers = 0;
  int inliers = 0;                    // homography inliers
  double bilateral_error_sum = 0;     // equation (1) summed over the survivors, pixels
  double bilateral_error_mean = 0;
  cv::Matx33d H = cv::Matx33d::eye(); // maps `from` pixels to `to` pixels
  std::vector<cv::Point2f> inlier_from, inlier_to;  // the homography's inliers
  std::vector<int> inlier_index;                    // their places in `from`
  std::optional<PlaneMotion> motion;  // from the decomposition, when K is known
};

// Bilateral epipolar error of one correspondence: d(p2, F p1) + d(p1, F^T p2).
double BilateralEpipolarError(const cv::Matx33d& F, const cv::Point2f& p1, const cv::Point2f& p2);

EgomotionResult EstimateEgomotion(const std::vector<cv::Point2f>& from,
                                  const std::vector<cv::Point2f>& to, const cv::Matx33d& K,
                                  const EgomotionOptions& options);

// The decomposition alone: solutions of H (from -> to) with every reference point in front of
// both cameras; the one whose plane normal is closest to the optical axis.
std::optional<PlaneMotion> DecomposeHomography(const cv::Matx33d& H, const cv::Matx33d& K,
                                               const std::vector<cv::Point2f>& from,
                                               const std::vector<cv::Point2f>& to);

}  // namespace rolamos
