// Matching detections to true boxes: suppression of overlapping windows and the operating point.
#pragma once

#include <vector>

#include "rolamos/box_detector.hpp"

namespace rolamos {

// Greedy: the best-scored box wins; boxes overlapping it by more than `iou`, or lying inside it
// (or around it) by more than `containment` of the smaller one's area, go. Best first.
std::vector<BoxDetection> SuppressBoxes(std::vector<BoxDetection> detections, double iou, double containment = 1.0);
// The score at which F1 (IoU 0.5) over all frames is highest.
double BestF1Threshold(const std::vector<std::vector<BoxDetection>>& detections,
                       const std::vector<std::vector<cv::Rect2d>>& truth);

}  // namespace rolamos
