#include "objects/colour_statistics.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {

namespace {

// The integral of a pixel image (constant over each pixel's square) over [0, x) x [0, y), for
// any real x, y: bilinear between the integral image's samples. Boxes with fractional edges then
// weigh their edge pixels by the part they cover, so a box and its mirror image agree exactly.
double IntegralAt(const cv::Mat& integral, double x, double y) {
  x = std::clamp(x, 0.0, integral.cols - 1.0);
  y = std::clamp(y, 0.0, integral.rows - 1.0);
  const int x0 = std::min(static_cast<int>(x), integral.cols - 2), y0 = std::min(static_cast<int>(y), integral.rows - 2);
  const double fx = x - x0, fy = y - y0;
  const double* r0 = integral.ptr<double>(y0);
  const double* r1 = integral.ptr<double>(y0 + 1);
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
}

double BoxIntegral(const cv::Mat& integral, const cv::Rect2d& r) {
  return IntegralAt(integral, r.br().x, r.br().y) - IntegralAt(integral, r.x, r.br().y) -
         IntegralAt(integral, r.br().x, r.y) + IntegralAt(integral, r.x, r.y);
}

}  // namespace

cv::Mat ColourStatistics(const cv::Mat& sample, const std::vector<cv::KeyPoint>& keypoints) {
  cv::Mat lab;
  sample.convertTo(lab, CV_32F, 1.0 / 255);
  cv::cvtColor(lab, lab, cv::COLOR_BGR2Lab);
  // Integral images of each channel and its square: any box's mean and variance in O(1).
  std::vector<cv::Mat> channels(3), sums(3), squares(3);
  cv::split(lab, channels);
  for (size_t c = 0; c < 3; ++c) cv::integral(channels[c], sums[c], squares[c], CV_64F, CV_64F);
  const cv::Rect2d image(0, 0, sample.cols, sample.rows);
  cv::Mat out(static_cast<int>(keypoints.size()), 96, CV_32F);
  for (int i = 0; i < out.rows; ++i) {
    const cv::KeyPoint& k = keypoints[static_cast<size_t>(i)];
    // The patch SIFT describes: centred on the keypoint's pixel centre, 6 x size across.
    const double side = k.size * 6.0, cell = side / 4;
    const double left = k.pt.x + 0.5 - side / 2, top = k.pt.y + 0.5 - side / 2;
    float* o = out.ptr<float>(i);
    for (int cy = 0; cy < 4; ++cy)
      for (int cx = 0; cx < 4; ++cx) {
        const cv::Rect2d box = cv::Rect2d(left + cx * cell, top + cy * cell, cell, cell) & image;
        const double area = box.area();
        for (size_t c = 0; c < 3; ++c) {
          const double mean = area > 0 ? BoxIntegral(sums[c], box) / area : 0;
          const double var = area > 0 ? BoxIntegral(squares[c], box) / area - mean * mean : 0;
          // L spans 0..100 and a, b about -60..60: one scale keeps them comparable.
          *o++ = static_cast<float>(mean / 50);
          *o++ = static_cast<float>(std::sqrt(std::max(0.0, var)) / 50);
        }
      }
  }
  return out;
}

}  // namespace rolamos
