#include "engine/motion_gate.h"

#include <cmath>

namespace rolamos {

bool MotionGateOptions::IsValid(std::string* error) const {
  if (!(gate_chi2 > 0) || min_jump_fraction < 0 || min_jump_degrees < 0 || min_jump_scale < 0 ||
      warmup_frames < 1 || !(noise_memory > 0 && noise_memory <= 1)) {
    *error = "Kalman gate settings must be positive (noise memory in (0, 1])";
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

cv::Matx33d HomographyOf(const FrameMotion& m, cv::Size frame) {
  const cv::Point2d c((frame.width - 1) / 2.0, (frame.height - 1) / 2.0);
  const double k = std::exp(m.log_scale), cs = k * std::cos(m.rotation), sn = k * std::sin(m.rotation);
  // p -> R s (p - c) + c + d
  return cv::Matx33d(cs, -sn, c.x + m.dx - (cs * c.x - sn * c.y), sn, cs, c.y + m.dy - (sn * c.x + cs * c.y), 0, 0, 1);
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
  base_noise_ = cv::Mat(4, 1, CV_64F);
  for (int i = 0; i < 4; ++i) {
    kf_.processNoiseCov.at<double>(8 + i, 8 + i) = q[i];
    kf_.processNoiseCov.at<double>(4 + i, 4 + i) = q[i] * 0.25;
    kf_.processNoiseCov.at<double>(i, i) = q[i] * 0.1;
    kf_.measurementNoiseCov.at<double>(i, i) = q[i];
    base_noise_.at<double>(i) = q[i];
  }
  observed_ = base_noise_.clone();
  kf_.errorCovPost = cv::Mat::eye(12, 12, CV_64F) * 1e4;
  kf_.statePost = cv::Mat::zeros(12, 1, CV_64F);
  seen_ = 0;
  predicted_ = false;
}

void MotionGate::Restart(const cv::Mat& z) {
  // The motion changed for real: start from it, keep what was learnt about the jitter.
  const cv::Mat observed = observed_.clone();
  Reset();
  observed_ = observed;
  for (int i = 0; i < 4; ++i)
    kf_.measurementNoiseCov.at<double>(i, i) = std::max(base_noise_.at<double>(i), observed_.at<double>(i));
  z.copyTo(kf_.statePost.rowRange(0, 4));
  kf_.errorCovPost = cv::Mat::eye(12, 12, CV_64F) * 1e2;
  seen_ = options_.warmup_frames;
}

cv::Mat MotionGate::Measurement(const FrameMotion& m) const {
  const double k = 1.0 / std::max(1, gap_);
  return (cv::Mat_<double>(4, 1) << m.dx * k, m.dy * k, m.rotation * k, m.log_scale * k);
}

void MotionGate::Predict(int gap) {
  gap_ = std::max(1, gap);
  if (!options_.enabled) return;
  kf_.predict();
  predicted_ = true;
}

GateVerdict MotionGate::Evaluate(const FrameMotion& m) const {
  GateVerdict v;
  if (!options_.enabled || !predicted_ || seen_ < options_.warmup_frames) return v;
  v.informed = true;
  const cv::Mat z = Measurement(m);
  const cv::Mat& H = kf_.measurementMatrix;
  const cv::Mat S = H * kf_.errorCovPre * H.t() + kf_.measurementNoiseCov;
  cv::Mat y = z - H * kf_.statePre;
  y.at<double>(2) = std::remainder(y.at<double>(2), 2 * CV_PI);
  v.distance2 = cv::Mat(y.t() * S.inv() * y).at<double>(0);
  const double size = std::max(frame_.width, frame_.height);
  const bool big_jump = std::hypot(y.at<double>(0), y.at<double>(1)) > options_.min_jump_fraction * size ||
                        std::abs(y.at<double>(2)) > options_.min_jump_degrees * CV_PI / 180 ||
                        std::abs(y.at<double>(3)) > options_.min_jump_scale;
  v.consistent = !(v.distance2 > options_.gate_chi2 && big_jump);
  return v;
}

void MotionGate::Accept(const FrameMotion& m) {
  if (!options_.enabled) return;
  if (!predicted_) Predict(gap_);
  const cv::Mat z = Measurement(m);
  if (!Evaluate(m).consistent) {
    Restart(z);
    predicted_ = false;
    return;
  }
  // The observed jitter: squared innovations of accepted frames, remembered with a short memory;
  // the measurement noise never falls below its floor.
  if (seen_ >= options_.warmup_frames) {
    cv::Mat y = z - kf_.measurementMatrix * kf_.statePre;
    y.at<double>(2) = std::remainder(y.at<double>(2), 2 * CV_PI);
    for (int i = 0; i < 4; ++i) {
      double& o = observed_.at<double>(i);
      o = (1 - options_.noise_memory) * o + options_.noise_memory * y.at<double>(i) * y.at<double>(i);
      kf_.measurementNoiseCov.at<double>(i, i) = std::max(base_noise_.at<double>(i), o);
    }
  }
  kf_.correct(z);
  ++seen_;
  predicted_ = false;
}

std::optional<FrameMotion> MotionGate::Predicted() const {
  if (!options_.enabled || !predicted_ || seen_ < options_.warmup_frames) return std::nullopt;
  const double k = std::max(1, gap_);
  FrameMotion m;
  m.dx = kf_.statePre.at<double>(0) * k;
  m.dy = kf_.statePre.at<double>(1) * k;
  m.rotation = kf_.statePre.at<double>(2) * k;
  m.log_scale = kf_.statePre.at<double>(3) * k;
  return m;
}

void MotionGate::Skip() {
  if (!options_.enabled || !predicted_) return;
  // Not stitched: the filter keeps its prediction (errorCovPost grows with the next predict).
  kf_.statePost = kf_.statePre.clone();
  kf_.errorCovPost = kf_.errorCovPre.clone();
  predicted_ = false;
}

double MotionGate::jitter_px() const {
  return std::sqrt(0.5 * (kf_.measurementNoiseCov.at<double>(0, 0) + kf_.measurementNoiseCov.at<double>(1, 1)));
}

}  // namespace rolamos
