// Exposure gains of overlapping images (a patch's frames, a map's patches): one gain each, so
// that their brightness agrees where they overlap, solved by least squares in log and held to 1
// on average so the whole does not drift darker or lighter. (OpenCV's block gain compensator
// solves the same equations; this one takes the images' own placements and no-data alpha.)
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// Exposure gains of a patch's frames: frame k's brightness times gain[k] agrees with its
// neighbours' where they overlap. `images` are the corrected frames (BGR, or BGRA with alpha for
// where they have data; any depth) reduced to
// `scale` of full resolution, `placements` full-resolution frame -> patch. Gains average 1 (in log).
std::vector<double> SolveExposureGains(const std::vector<cv::Mat>& images, double scale,
                                       const std::vector<cv::Matx33d>& placements, double prior);

}  // namespace rolamos
