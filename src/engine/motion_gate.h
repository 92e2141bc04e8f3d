// Stage 3: consistency check. A Kalman filter with a constant-acceleration model follows the
// frame-to-frame motion (translation x, y, rotation, log scale, from the similarity closest to
// the homography). A frame whose motion leaves the gate (Mahalanobis distance of the innovation,
// and a jump larger than a physical floor: e.g. a 180-degree turn or a leap across the frame) is
// not stitched; "aliasing constraint" of the paper: consecutive frames are close in time.
#pragma once

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
  int warmup_frames = 3;              // accepted while the filter learns
  // After this many rejections in a row whose motions agree with each other, the vehicle has
  // changed its motion for real: the filter restarts from it instead of rejecting the rest.
  int reacquire_after = 2;

  bool IsValid(std::string* error) const;
};

// Similarity parameters of a frame-to-frame homography about the frame centre.
struct FrameMotion {
  double dx = 0, dy = 0, rotation = 0, log_scale = 0;  // pixels, radians, log
};
FrameMotion MotionOf(const cv::Matx33d& H, cv::Size frame);

class MotionGate {
 public:
  MotionGate(const MotionGateOptions& options, cv::Size frame);
  // Checks the motion measured over `gap` input frames (rejected frames in between make gaps);
  // the filter follows motion per frame. Accepted ones update it. Returns "" or the reason.
  std::string Check(const FrameMotion& m, int gap = 1);
  void Reset();
  double last_distance() const { return last_d2_; }

 private:
  MotionGateOptions options_;
  cv::Size frame_;
  void Restart(const cv::Mat& z);

  cv::KalmanFilter kf_;
  int seen_ = 0;
  int rejected_in_row_ = 0;
  cv::Mat last_rejected_;  // the motion of the last rejected frame
  double last_d2_ = 0;
};

}  // namespace rolamos
