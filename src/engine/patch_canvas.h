// The patch being built in RAM: weighted colour sums and weight sums over a canvas that grows
// with the frames, in patch coordinates (the first frame's pixel grid). Its pixel budget is the
// paper's memory management: Fits() says whether one more frame keeps the patch within it.
#pragma once

#include <opencv2/core.hpp>

#include "engine/feather.h"

namespace rolamos {

class PatchCanvas {
 public:
  explicit PatchCanvas(long long pixel_budget) : budget_(pixel_budget) {}

  // Bounding box (patch coordinates) of a frame warped by frame_to_patch.
  static cv::Rect2d FrameBounds(const cv::Matx33d& frame_to_patch, cv::Size frame);
  // Whether the canvas, grown to hold `bounds`, stays within the budget.
  bool Fits(const cv::Rect2d& bounds) const;
  bool empty() const { return sum_.empty(); }
  // Warps and accumulates a frame (BGR 8-bit) with its feather weights.
  void Add(const cv::Mat& frame, const cv::Mat& weights, const cv::Matx33d& frame_to_patch);
  // The blended mosaic (BGRA 8-bit, alpha 0 where nothing was added) of a patch rectangle.
  cv::Mat Render(const cv::Rect& patch_rect) const;
  // The mosaic seen from a frame: gray pixels and a validity mask in that frame's coordinates,
  // at `scale` of its resolution (for ECC refinement).
  void ViewFromFrame(const cv::Matx33d& frame_to_patch, cv::Size frame, double scale,
                     cv::Mat* gray, cv::Mat* mask) const;
  // Canvas rectangle in patch coordinates: the patch image's pixel (0, 0) is at origin().
  cv::Rect extent() const { return extent_; }
  cv::Point origin() const { return extent_.tl(); }
  long long pixel_budget() const { return budget_; }
  size_t memory_bytes() const { return sum_.total() * sum_.elemSize() + weight_.total() * weight_.elemSize(); }

 private:
  void GrowTo(const cv::Rect& needed);

  long long budget_;
  cv::Rect extent_;  // allocated, in patch coordinates (with room to grow)
  cv::Rect data_;    // covered by frames so far: what the budget counts
  cv::Mat sum_;      // CV_32FC3: sum of weight * colour
  cv::Mat weight_;   // CV_32F: sum of weights
};

}  // namespace rolamos
