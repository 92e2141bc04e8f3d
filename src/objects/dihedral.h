// The eight orientations of a square sample (quarter turns, each with and without a mirror) as
// permutations of its dense descriptors: a SIFT descriptor of the turned or mirrored image, at
// the point its patch moved to, is the original descriptor with its 4 x 4 cells and 8
// orientation bins permuted; so are the colour statistics' cells. A downward-looking camera sees
// an object in any orientation; describing all eight costs permutations, not extractions.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

class DihedralTransform {
 public:
  // t in 0..7: (t & 3) quarter turns clockwise, then, if t & 4, a mirror left to right.
  explicit DihedralTransform(int t);
  // Rows of SIFT descriptors (any multiple of 128 columns: one block per channel).
  cv::Mat Sift(const cv::Mat& descriptors) const;
  // Rows of colour statistics (ColourStatistics: 16 cells of 6 values).
  cv::Mat ColourStatistics(const cv::Mat& statistics) const;
  // Where a point of a side x side sample goes.
  cv::Point2f Point(cv::Point2f p, float side) const;

 private:
  int t_;
  std::vector<int> sift_, colour_;  // destination index of each source index
};

}  // namespace rolamos
