// Stage 4: sub-pixel refinement of a frame's placement against the mosaic built so far with the
// enhanced correlation coefficient (cv::findTransformECC), coarse to fine on a small pyramid so
// it stays fast. ECC is invariant to gain and offset, so vignetting and haze do not pull it.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace rolamos {

struct EccOptions {
  bool enabled = true;
  double scale = 0.25;       // finest level, relative to the frame
  int levels = 1;            // pyramid levels (each half the one before); features are
                             // already within a pixel or two, so one level suffices
  int iterations = 15;
  double epsilon = 1e-4;  // stop when the correlation improves by less
  double min_correlation = 0.6;  // below this the refinement is not trusted
  double max_shift_px = 8.0;     // a correction larger than this (full-res pixels) is refused
  std::string motion = "homography";  // translation | euclidean | affine | homography
  bool IsValid(std::string* error) const;
};

class PatchCanvas;

struct EccResult {
  bool applied = false;
  double correlation = 0;
  cv::Matx33d frame_to_patch = cv::Matx33d::eye();
};

// `frame_gray` is the frame (8-bit gray, full res); `frame_to_patch` the feature estimate.
// `frame_mask` (optional, the frame's size, non-zero = usable) leaves static overlays out.
EccResult RefineWithEcc(const cv::Mat& frame_gray, const cv::Matx33d& frame_to_patch,
                        const PatchCanvas& canvas, const EccOptions& options,
                        const cv::Mat& frame_mask = cv::Mat());

}  // namespace rolamos
