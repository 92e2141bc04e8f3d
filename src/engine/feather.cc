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

FeatherCode::FeatherCode(const cv::Mat& weights) {
  CV_Assert(weights.type() == CV_32F);
  // w = exp((b - 255) / k) with b = 1 at the floor.
  const double k = 254.0 / std::log(1.0 / kFeatherFloor);
  weight[0] = 0.f;
  for (int b = 1; b < 256; ++b) weight[static_cast<size_t>(b)] = static_cast<float>(std::exp((b - 255) / k));
  code.create(weights.size(), CV_8U);
  for (int y = 0; y < weights.rows; ++y) {
    const float* w = weights.ptr<float>(y);
    uchar* c = code.ptr<uchar>(y);
    for (int x = 0; x < weights.cols; ++x) {
      const bool edge = x == 0 || y == 0 || x == weights.cols - 1 || y == weights.rows - 1;
      if (edge || !(w[x] > 0)) {
        c[x] = 0;
        continue;
      }
      const double b = 255.0 + k * std::log(std::min(1.0f, w[x]));
      c[x] = static_cast<uchar>(std::clamp(std::lround(b), 1L, 255L));
    }
  }
}

FeatherCode FeatherCode::Part(const cv::Rect& r) const {
  FeatherCode part;
  part.code = code(r);
  part.weight = weight;
  return part;
}

}  // namespace rolamos
