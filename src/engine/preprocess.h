// Stage 1: pre-processing. Undistortion from an OpenCV calibration; the robust bilateral and
// temporal filter (spatial bilateral smoothing, then a temporal term that averages with the
// previous filtered frame brought into this frame by the egomotion, weighted down where the two
// disagree, so particles and moving things are not smeared); contrast normalisation (CLAHE on
// luminance) for the detection image only, never for blended pixels.
#pragma once

#include <mutex>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

namespace rolamos {

struct Calibration {
  cv::Matx33d camera_matrix = cv::Matx33d::eye();
  cv::Mat distortion;  // 1xN, OpenCV order
  cv::Size image_size;
};

// Reads an OpenCV FileStorage file (YAML, XML or JSON) with camera_matrix and
// distortion_coefficients (and optionally image_width/image_height). Throws Error naming the file
// and the field.
Calibration ReadCalibration(const std::string& path);

struct PreprocessOptions {
  std::string calibration;       // "" = frames are already rectified
  // Without a calibration: the horizontal field of view (degrees, in water) the camera matrix
  // is made from: the camera each frame is placed through when a patch is adjusted.
  double fov_deg = 70;
  bool bilateral = true;
  int bilateral_diameter = 5;
  double bilateral_sigma_color = 12.0;
  double bilateral_sigma_space = 3.0;
  bool temporal = true;
  double temporal_weight = 0.5;  // weight of the previous frame where the two agree
  double temporal_tolerance = 16.0;  // grey levels: differences above this are not averaged
  bool clahe = true;
  // Dark, hazy seafloor needs a strong local stretch for features to be found at all.
  double clahe_clip = 4.0;
  // Marine snow: bright specks up to this radius (pixels of the detection image) are left out of
  // detection (masked, not filtered away: filtering would move the features around them), so
  // features are not spent on particles that move on their own. 0 = off.
  int despeckle_px = 0;
  double speck_contrast = 12.0;  // grey levels above the surroundings that make a speck

  bool IsValid(std::string* error) const;
};

class Preprocessor {
 public:
  explicit Preprocessor(const PreprocessOptions& options);
  // Undistortion and bilateral smoothing. Checks the frame size against the calibration.
  // Thread-safe: several frames may be filtered at once.
  cv::Mat Spatial(const cv::Mat& frame);
  // Its two halves: every frame is undistorted (the geometry needs it); only the frames that are
  // blended are smoothed.
  cv::Mat Undistort(const cv::Mat& frame);
  cv::Mat Bilateral(const cv::Mat& frame) const;
  // The detection image: gray, reduced to `scale` of the frame, contrast-normalised; with
  // `usable`, also where features may be found (0 on marine snow specks).
  cv::Mat DetectionImage(const cv::Mat& frame, double scale = 1.0, cv::Mat* usable = nullptr) const;
  // The temporal term: `previous` (filtered, BGR) seen through current_to_previous.
  cv::Mat Temporal(const cv::Mat& current, const cv::Mat& previous,
                   const cv::Matx33d& current_to_previous) const;
  // The camera matrix of the (rectified) frames, or a default for frames of `size`.
  cv::Matx33d CameraMatrix(cv::Size size) const;
  const std::optional<Calibration>& calibration() const { return calibration_; }

 private:
  PreprocessOptions options_;
  std::optional<Calibration> calibration_;
  mutable std::mutex mutex_;  // guards the undistortion maps, made for the first frame's size
  cv::Matx33d rectified_K_ = cv::Matx33d::eye();  // camera of the undistorted frames
  cv::Mat map_x_, map_y_;
};

}  // namespace rolamos
