#include "engine/self_calibration.h"

#include <opencv2/calib3d.hpp>

#include "rolamos/error.hpp"

namespace rolamos {

namespace {

int InliersWith(const std::vector<Matches>& pairs, const cv::Matx33d& K, double k1) {
  const cv::Mat D = (cv::Mat_<double>(1, 4) << k1, 0, 0, 0);
  int total = 0;
  for (const auto& m : pairs) {
    std::vector<cv::Point2f> a, b;
    cv::undistortPoints(m.from, a, cv::Mat(K), D, cv::noArray(), cv::Mat(K));
    cv::undistortPoints(m.to, b, cv::Mat(K), D, cv::noArray(), cv::Mat(K));
    std::vector<uchar> mask;
    cv::findHomography(a, b, cv::USAC_MAGSAC, 2.0, mask, 5000, 0.999);
    for (uchar v : mask) total += v;
  }
  return total;
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
  std::vector<Features> found;
  for (const auto& g : gray) found.push_back(extractor.Extract(g));
  std::vector<Matches> pairs;
  for (size_t i = 0; i + 1 < found.size(); ++i) {
    Matches m = MatchFeatures(found[i + 1], found[i], fo);
    if (m.from.size() >= 30) pairs.push_back(std::move(m));
  }
  r.pairs = static_cast<int>(pairs.size());
  r.calibration.camera_matrix = K;
  r.calibration.image_size = size;
  r.calibration.distortion = cv::Mat::zeros(1, 4, CV_64F);
  if (pairs.empty()) return r;
  r.inliers_uncorrected = InliersWith(pairs, K, 0.0);
  // Coarse grid, then a finer one around the best.
  double best = 0;
  int best_score = r.inliers_uncorrected;
  for (double k1 = -0.4; k1 <= 0.8 + 1e-9; k1 += 0.05) {
    const int s = InliersWith(pairs, K, k1);
    if (s > best_score) best_score = s, best = k1;
  }
  const double centre = best;
  for (double k1 = centre - 0.04; k1 <= centre + 0.04 + 1e-9; k1 += 0.01) {
    const int s = InliersWith(pairs, K, k1);
    if (s > best_score) best_score = s, best = k1;
  }
  if (best_score < (1.0 + min_gain) * r.inliers_uncorrected) {
    r.inliers_corrected = r.inliers_uncorrected;
    return r;  // no clear gain: leave the frames alone
  }
  r.k1 = best;
  r.inliers_corrected = best_score;
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
