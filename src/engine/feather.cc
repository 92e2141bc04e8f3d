#include "engine/feather.h"

#include <cmath>

namespace rolamos {

cv::Mat FeatherWeights(cv::Size frame, double sigma_fraction) {
  if (sigma_fraction <= 0) return cv::Mat(frame, CV_32F, cv::Scalar(1.0f));
  const double sx = sigma_fraction * frame.width, sy = sigma_fraction * frame.height;
  const double cx = (frame.width - 1) / 2.0, cy = (frame.height - 1) / 2.0;
  cv::Mat wx(1, frame.width, CV_32F), wy(frame.height, 1, CV_32F);
  for (int x = 0; x < frame.width; ++x)
    wx.at<float>(x) = static_cast<float>(std::exp(-0.5 * (x - cx) * (x - cx) / (sx * sx)));
  for (int y = 0; y < frame.height; ++y)
    wy.at<float>(y) = static_cast<float>(std::exp(-0.5 * (y - cy) * (y - cy) / (sy * sy)));
  cv::Mat w = wy * wx;  // separable
  return cv::max(w, kFeatherFloor);
}

}  // namespace rolamos
