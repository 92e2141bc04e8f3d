#include "engine/motion_gate.h"

#include <cmath>

namespace rolamos {

bool MotionGateOptions::IsValid(std::string* error) const {
  if (!(gate_chi2 > 0) || min_jump_fraction < 0 || min_jump_degrees < 0 || min_jump_scale < 0 ||
      warmup_frames < 1) {
    *error = "Kalman gate settings must be positive";
    return false;
  }
  return true;
}

FrameMotion MotionOf(const cv::Matx33d& H, cv::Size frame) {
  const cv::Point2d c((frame.width - 1) / 2.0, (frame.height - 1) / 2.0);
  auto map = [&](cv::Point2d p) {
    cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
    return cv::Point2d(q[0] / q[2], q[1] / q[2]);
  };
  const cv::Point2d c2 = map(c), u = map(c + cv::Point2d(100, 0)) - c2;
  FrameMotion m;
  m.dx = c2.x - c.x;
  m.dy = c2.y - c.y;
  m.rotation = std::atan2(u.y, u.x);
  m.log_scale = std::log(std::max(1e-9, std::hypot(u.x, u.y) / 100.0));
  return m;
}

MotionGate::MotionGate(const MotionGateOptions& options, cv::Size frame)
    : options_(options), frame_(frame) {
  Reset();
}

void MotionGate::Reset() {
  // State per component: motion, its rate and its acceleration (12); measured: the motion (4).
  kf_.init(12, 4, 0, CV_64F);
  cv::Mat A = cv::Mat::eye(12, 12, CV_64F);
  for (int i = 0; i < 4; ++i) {
    A.at<double>(i, 4 + i) = 1.0;
    A.at<double>(i, 8 + i) = 0.5;
    A.at<double>(4 + i, 8 + i) = 1.0;
  }
  kf_.transitionMatrix = A;
  kf_.measurementMatrix = cv::Mat::zeros(4, 12, CV_64F);
  for (int i = 0; i < 4; ++i) kf_.measurementMatrix.at<double>(i, i) = 1.0;
  const double px = 0.02 * std::max(frame_.width, frame_.height);
  const double q[4] = {px * px, px * px, 0.02 * 0.02, 0.01 * 0.01};
  kf_.processNoiseCov = cv::Mat::zeros(12, 12, CV_64F);
  kf_.measurementNoiseCov = cv::Mat::zeros(4, 4, CV_64F);
  for (int i = 0; i < 4; ++i) {
    kf_.processNoiseCov.at<double>(8 + i, 8 + i) = q[i];
    kf_.processNoiseCov.at<double>(4 + i, 4 + i) = q[i] * 0.25;
    kf_.processNoiseCov.at<double>(i, i) = q[i] * 0.1;
    kf_.measurementNoiseCov.at<double>(i, i) = q[i];
  }
  kf_.errorCovPost = cv::Mat::eye(12, 12, CV_64F) * 1e4;
  kf_.statePost = cv::Mat::zeros(12, 1, CV_64F);
  seen_ = 0;
  rejected_in_row_ = 0;
  last_rejected_.release();
}

void MotionGate::Restart(const cv::Mat& z) {
  Reset();
  z.copyTo(kf_.statePost.rowRange(0, 4));
  kf_.errorCovPost = cv::Mat::eye(12, 12, CV_64F) * 1e2;
  seen_ = options_.warmup_frames;
}

std::string MotionGate::Check(const FrameMotion& m, int gap) {
  const double k = 1.0 / std::max(1, gap);
  const cv::Mat z = (cv::Mat_<double>(4, 1) << m.dx * k, m.dy * k, m.rotation * k, m.log_scale * k);
  if (!options_.enabled) return "";
  cv::Mat predicted = kf_.predict();
  if (seen_ < options_.warmup_frames) {
    kf_.correct(z);
    ++seen_;
    return "";
  }
  const cv::Mat H = kf_.measurementMatrix;
  const cv::Mat S = H * kf_.errorCovPre * H.t() + kf_.measurementNoiseCov;
  cv::Mat y = z - H * predicted;
  y.at<double>(2) = std::remainder(y.at<double>(2), 2 * CV_PI);
  last_d2_ = cv::Mat(y.t() * S.inv() * y).at<double>(0);
  const double size = std::max(frame_.width, frame_.height);
  const bool big_jump = std::hypot(y.at<double>(0), y.at<double>(1)) > options_.min_jump_fraction * size ||
                        std::abs(y.at<double>(2)) > options_.min_jump_degrees * CV_PI / 180 ||
                        std::abs(y.at<double>(3)) > options_.min_jump_scale;
  if (last_d2_ > options_.gate_chi2 && big_jump) {
    // Consecutive rejected frames that move alike: a real change of motion, not an outlier.
    const bool agrees_with_last =
        !last_rejected_.empty() &&
        std::hypot(z.at<double>(0) - last_rejected_.at<double>(0),
                   z.at<double>(1) - last_rejected_.at<double>(1)) < options_.min_jump_fraction * size &&
        std::abs(std::remainder(z.at<double>(2) - last_rejected_.at<double>(2), 2 * CV_PI)) <
            options_.min_jump_degrees * CV_PI / 180 &&
        std::abs(z.at<double>(3) - last_rejected_.at<double>(3)) < options_.min_jump_scale;
    ++rejected_in_row_;
    if (agrees_with_last && rejected_in_row_ >= options_.reacquire_after) {
      Restart(z);
      return "";
    }
    last_rejected_ = z.clone();
    // Not stitched: the filter keeps its prediction (errorCovPost grows with the next predict).
    kf_.statePost = kf_.statePre.clone();
    kf_.errorCovPost = kf_.errorCovPre.clone();
    return "kalman_gate";
  }
  rejected_in_row_ = 0;
  last_rejected_.release();
  kf_.correct(z);
  ++seen_;
  return "";
}

}  // namespace rolamos
