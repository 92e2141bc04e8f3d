#include "engine/self_calibration.h"


#include <cmath>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"

namespace rolamos {

namespace {

// Truncated squared transfer error of all matches under the homography each pair fits best
// (a smooth score: inlier counts saturate and leave a broad plateau), and the inliers.
struct Score {
  double cost = 0;
  int inliers = 0;
};

Score ScoreWith(const std::vector<Matches>& pairs, const cv::Matx33d& K, double k1) {
  const cv::Mat D = (cv::Mat_<double>(1, 4) << k1, 0, 0, 0);
  const double t2 = 3.0 * 3.0;
  Score score;
  for (const auto& m : pairs) {
    std::vector<cv::Point2f> a, b;
    cv::undistortPoints(m.from, a, cv::Mat(K), D, cv::noArray(), cv::Mat(K));
    cv::undistortPoints(m.to, b, cv::Mat(K), D, cv::noArray(), cv::Mat(K));
    std::vector<uchar> mask;
    cv::Mat H = cv::findHomography(a, b, cv::USAC_MAGSAC, 2.0, mask, 5000, 0.999);
    if (H.empty()) {
      score.cost += t2 * a.size();
      continue;
    }
    std::vector<cv::Point2f> ia, ib;
    for (size_t i = 0; i < a.size(); ++i)
      if (mask[i]) ia.push_back(a[i]), ib.push_back(b[i]);
    if (ia.size() >= 8) {
      cv::Mat refined = cv::findHomography(ia, ib, 0);
      if (!refined.empty()) H = refined;
    }
    std::vector<cv::Point2f> mapped;
    cv::perspectiveTransform(a, mapped, H);
    for (size_t i = 0; i < a.size(); ++i) {
      const double e2 = std::pow(mapped[i].x - b[i].x, 2) + std::pow(mapped[i].y - b[i].y, 2);
      score.cost += std::min(e2, t2);
      score.inliers += e2 < 4.0;
    }
  }
  return score;
}

}  // namespace

SelfCalibrationResult EstimateRadialDistortion(const std::vector<cv::Mat>& gray,
                                               const FeatureOptions& features, double min_gain) {
  SelfCalibrationResult r;
  if (gray.size() < 2) Fail("self-calibration", "needs at least two frames");
  const cv::Size size = gray[0].size();
  const double f = 0.9 * size.width;
  const cv::Matx33d K(f, 0, (size.width - 1) / 2.0, 0, f, (size.height - 1) / 2.0, 0, 0, 1);
  // More features than tracking uses: the score must not be noise.
  FeatureOptions fo = features;
  fo.max_features = std::max(fo.max_features, 3000);
  fo.detect_scale = std::max(fo.detect_scale, 0.5);
  FeatureExtractor extractor(fo);
  std::vector<Features> found(gray.size());
  // On every core: a run's start waits for this (the extractor makes a detector per call).
  cv::parallel_for_(cv::Range(0, static_cast<int>(gray.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) found[size_t(i)] = extractor.Extract(gray[size_t(i)]);
  });
  std::vector<Matches> pairs;
  for (size_t i = 0; i + 1 < found.size(); ++i) {
    Matches m = MatchFeatures(found[i + 1], found[i], fo);
    if (m.from.size() >= 30) pairs.push_back(std::move(m));
  }
  r.pairs = static_cast<int>(pairs.size());
  r.calibration.camera_matrix = K;
  r.calibration.image_size = size;
  r.calibration.distortion = cv::Mat::zeros(1, 4, CV_64F);
  if (pairs.size() < 3) {
    r.why_none = "too few pairs of frames match to tell (" + std::to_string(pairs.size()) + " of at least 3)";
    return r;
  }
  const Score zero = ScoreWith(pairs, K, 0.0);
  r.inliers_uncorrected = zero.inliers;
  // Coarse grid, then a finer one around the best. One after the other on purpose: MAGSAC draws
  // from the thread's random generator, so scores made on several threads differ run to run.
  double best = 0;
  Score best_score = zero;
  for (double k1 = -0.4; k1 <= 0.8 + 1e-9; k1 += 0.05) {
    const Score s = ScoreWith(pairs, K, k1);
    if (s.cost < best_score.cost) best_score = s, best = k1;
  }
  const double centre = best;
  for (double k1 = centre - 0.04; k1 <= centre + 0.04 + 1e-9; k1 += 0.01) {
    const Score s = ScoreWith(pairs, K, k1);
    if (s.cost < best_score.cost) best_score = s, best = k1;
  }
  if (best_score.cost > (1.0 - min_gain) * zero.cost || best_score.inliers < 150) {
    r.inliers_corrected = r.inliers_uncorrected;
    r.why_none = best_score.inliers < 150 ? "too few matches agree to tell (" + std::to_string(best_score.inliers) + " of at least 150)"
                                          : "no distortion lowers the error clearly";
    return r;  // leave the frames alone
  }
  r.k1 = best;
  r.inliers_corrected = best_score.inliers;
  r.calibration.distortion.at<double>(0) = best;
  return r;
}

void WriteCalibration(const std::string& path, const Calibration& c) {
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  if (!fs.isOpened()) Fail(path, "cannot be written");
  fs << "image_width" << c.image_size.width << "image_height" << c.image_size.height;
  fs << "camera_matrix" << cv::Mat(c.camera_matrix);
  fs << "distortion_coefficients" << c.distortion;
}

}  // namespace rolamos
