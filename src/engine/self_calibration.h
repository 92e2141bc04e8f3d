// Radial distortion from the survey itself, for frames that come without a calibration: the
// coefficient k1 (principal point at the centre, focal length 0.9 x width assumed) with which the
// matches between consecutive frames agree best with one homography (least truncated squared
// transfer error). A flat seafloor seen through
// a distorting lens only fits homographies once the distortion is taken out.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "engine/preprocess.h"

namespace rolamos {

struct SelfCalibrationResult {
  Calibration calibration;
  double k1 = 0;
  int pairs = 0;
  int inliers_uncorrected = 0;  // matches within 2 px of their pair's homography, k1 = 0
  int inliers_corrected = 0;    // the same at the chosen k1
  std::string why_none;         // why k1 was left at 0, when it was
};

// `gray` are the first frames of the survey in order. k1 stays 0 unless it lowers the error by
// `min_gain` (frames without distortion keep their pixels as they are), over at least three pairs
// of frames and 150 matches that agree: a pair or two of dim frames under the lights' cone fit a
// false distortion (one pair, 23 -> 26 inliers, gave k1 = -0.14 and a 16 px map).
SelfCalibrationResult EstimateRadialDistortion(const std::vector<cv::Mat>& gray,
                                               const FeatureOptions& features,
                                               double min_gain = 0.05);

// Writes an OpenCV FileStorage calibration (what ReadCalibration reads).
void WriteCalibration(const std::string& path, const Calibration& calibration);

}  // namespace rolamos
