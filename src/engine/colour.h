// Colour: what the eye reads first in a map. Three corrections, each estimated from the survey
// itself, applied to the frames before they are blended (in float, so nothing clips on the way):
//  - lighting (flat field): the lens's vignetting and the cone of the vehicle's lights are fixed
//    in the frame while the seafloor moves under them, so the mean log-brightness of many frames
//    at a pixel is the lighting there plus a constant; it is fitted as a smooth polynomial;
//  - exposure: each frame's gain, solved so that overlapping frames agree (log least squares,
//    held to 1 on average so the patch does not drift darker or lighter);
//  - water colour: per-channel gains that make the survey's mean colour grey (the water eats red
//    first), from the mean over every frame seen.
// The estimates grow with the survey and are frozen after `freeze_frames` frames, so that every
// later patch gets the same correction; they are kept in the store (lighting.json).
#pragma once

#include <array>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct ColourOptions {
  bool lighting = true;
  bool exposure = true;
  bool water_colour = true;
  int degree = 4;             // of the lighting polynomial in x and y
  int freeze_frames = 40;     // the survey-wide estimates stop changing after this many frames
  double exposure_prior = 0.05;  // how strongly each gain is held to the patch's average
  bool any() const { return lighting || exposure || water_colour; }
  bool IsValid(std::string* error) const;
};

// The survey's lighting and water colour, learnt from frames as they come.
class ColourModel {
 public:
  explicit ColourModel(const ColourOptions& options);
  // A frame as blended (BGR 8-bit), with the pixels to use (non-zero; may be empty).
  void Add(const cv::Mat& frame, const cv::Mat& usable);
  int frames() const { return frames_; }
  bool frozen() const { return frames_ >= options_.freeze_frames; }
  // Per-pixel multiplier (CV_32FC3, the frame's size) that removes the lighting and the water's
  // colour: corrected = frame x Correction(). Identity until a few frames were seen.
  cv::Mat Correction(cv::Size frame) const;
  // JSON of the model (lighting.json), and back.
  std::string ToJson() const;
  static ColourModel FromJson(const std::string& text, const ColourOptions& options, const std::string& where);

 private:
  ColourOptions options_;
  int frames_ = 0;
  cv::Size grid_{48, 36};
  cv::Mat log_sum_;   // CV_64FC3, grid: sum of log brightness
  cv::Mat count_;     // CV_64F, grid: frames that saw the cell
  std::array<double, 3> mean_sum_{};  // sum of each channel's mean brightness
  // Fitted when frozen (or on demand): polynomial coefficients per channel, white-balance gains.
  mutable std::vector<std::array<double, 3>> coefficients_;
  mutable std::array<double, 3> balance_{1, 1, 1};
  mutable int fitted_at_ = -1;
  void Fit() const;
};

}  // namespace rolamos
