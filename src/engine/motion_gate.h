// Stage 3: consistency check (section 3.2 of the paper). A Kalman filter with a
// constant-acceleration model follows the frame-to-frame motion (translation x, y, rotation, log
// scale, from the similarity closest to the homography). It arbitrates rather than vetoes: the
// engine asks how far each candidate registration of a frame is from the prediction (Mahalanobis
// distance of the innovation, and a jump larger than a physical floor) and prefers the consistent
// one; a well-supported registration the model did not predict is a real change of course (a lane
// join turned 180 degrees) and restarts the filter from it. The measurement noise follows the
// jitter the filter observes, so a vehicle that rolls and pitches from frame to frame widens the
// gate instead of being rejected by it.
#pragma once

#include <optional>

#include <string>

#include <opencv2/core.hpp>
#include <opencv2/video/tracking.hpp>

namespace rolamos {

struct MotionGateOptions {
  bool enabled = true;
  double gate_chi2 = 18.47;           // chi-square, 4 dof, p = 0.999
  double min_jump_fraction = 0.15;    // deviations below this fraction of the frame always pass
  double min_jump_degrees = 25.0;     // and below this rotation
  double min_jump_scale = 0.08;       // and below this relative scale change
  int warmup_frames = 3;              // motions learnt from before the gate judges (not informed)
  double noise_memory = 0.1;          // weight of each new innovation in the observed jitter

  bool IsValid(std::string* error) const;
};

// Similarity parameters of a frame-to-frame homography about the frame centre.
struct FrameMotion {
  double dx = 0, dy = 0, rotation = 0, log_scale = 0;  // pixels, radians, log
};
FrameMotion MotionOf(const cv::Matx33d& H, cv::Size frame);
// The similarity about the frame centre with these parameters (MotionOf's inverse for similarities).
cv::Matx33d HomographyOf(const FrameMotion& m, cv::Size frame);

struct GateVerdict {
  double distance2 = 0;    // squared Mahalanobis distance of the innovation
  bool consistent = true;  // within the gate (or below the physical floor, or still learning)
  bool informed = false;   // the filter has learnt the motion: `consistent` vouches for something
};

class MotionGate {
 public:
  MotionGate(const MotionGateOptions& options, cv::Size frame);
  // Once per frame that is to be registered, before Evaluate: the prediction `gap` input frames
  // after the last accepted one (rejected frames in between make gaps).
  void Predict(int gap = 1);
  // How a candidate motion (over the gap) agrees with the prediction. Does not change the filter.
  GateVerdict Evaluate(const FrameMotion& m) const;
  // The frame was stitched with motion `m`: a consistent motion updates the filter, an
  // inconsistent one (kept on its geometric support) restarts it from that motion.
  void Accept(const FrameMotion& m);
  // The frame was not stitched: the filter keeps its prediction.
  void Skip();
  void Reset();
  // The motion the filter expects over the gap given to Predict, once it has learnt the motion
  // (nothing while it learns, or when the gate is off).
  std::optional<FrameMotion> Predicted() const;
  // Standard deviation of the observed frame-to-frame jitter in translation, pixels.
  double jitter_px() const;

 private:
  cv::Mat Measurement(const FrameMotion& m) const;
  void Restart(const cv::Mat& z);

  MotionGateOptions options_;
  cv::Size frame_;
  cv::KalmanFilter kf_;
  cv::Mat base_noise_;  // 4 x 1: the measurement noise floor (variances)
  cv::Mat observed_;    // 4 x 1: running mean of squared innovations of accepted frames
  int seen_ = 0;
  int gap_ = 1;
  bool predicted_ = false;
};

}  // namespace rolamos
