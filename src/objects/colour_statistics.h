// Local colour statistics (Perronnin et al.), the colour descriptor beside SIFT: the mean and
// standard deviation of L, a and b in the 4 x 4 cells of each keypoint's SIFT patch.
#pragma once

#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

namespace rolamos {

// 96 values per keypoint (rows, CV_32F) of a BGR 8-bit sample; a patch spans 6 x the keypoint's
// size around its pixel centre, as OpenCV's SIFT does.
cv::Mat ColourStatistics(const cv::Mat& sample, const std::vector<cv::KeyPoint>& keypoints);

}  // namespace rolamos
