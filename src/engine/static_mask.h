// Static overlays: what a survey camera burns into every frame (a timestamp, laser scale dots,
// the edge of the housing) does not move with the seafloor. Matching locks onto it and returns no
// motion, and blending smears it over the map. It is found from the first frames of a survey,
// while the seafloor moves under them: at an overlay pixel the mean of the frames keeps its
// edges (the gradient of the mean is as strong as the mean of the gradients), where the moving
// seafloor averages out. The mask is left out of feature detection, ECC and blending.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct StaticMaskOptions {
  int frames = 24;             // frames looked at, from the start of the survey
  int min_frames = 12;         // with fewer, overlays cannot be told from the seafloor
  double scale = 0.25;         // resolution of the analysis
  double min_ratio = 0.55;     // |grad mean| / mean |grad| above which an edge is fixed in the image
  double min_edge = 4.0;       // grey levels per pixel: weaker edges are noise
  int min_area_px = 8;         // connected marks smaller than this (analysis pixels) are chance
  double grow = 0.012;         // the mask is grown by this fraction of the frame width, over glow and blur
  // A larger mask means the camera hardly moved: none is used. A part of the vehicle in view (a
  // skid, a manipulator, a sampling basket) takes a sixth of the frame or more: at 0.15 such a
  // part was not masked and was smeared along the map.
  double max_fraction = 0.35;

  bool IsValid(std::string* error) const;
};

struct StaticMask {
  cv::Mat mask;       // CV_8U, the frames' size, 255 = fixed in the image (left out); empty = none
  double fraction = 0;
  std::string note;   // what was found, or why no mask is used
  // False when these frames cannot tell (too few, or the seafloor hardly moves under them: a
  // descent through open water, a vehicle holding still): later frames may.
  bool conclusive = true;
};

// From frames (BGR or gray, one size).
StaticMask EstimateStaticMask(const std::vector<cv::Mat>& frames, const StaticMaskOptions& options);

// A mask image given by the user: white (non-zero) where the frames hold a fixed overlay.
// Resized (nearest) to the frames' size. Throws Error naming the file.
cv::Mat ReadStaticMask(const std::string& path, cv::Size frame);

}  // namespace rolamos
