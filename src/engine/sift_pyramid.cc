#include "engine/sift_pyramid.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {

namespace {
constexpr float kInitSigma = 0.5f;  // the blur the input image is assumed to have (OpenCV's)
}  // namespace

cv::Mat SiftBaseImage(const cv::Mat& gray, bool doubled, float sigma) {
  cv::Mat f, out;
  gray.convertTo(f, CV_32F, 1, 0);
  if (doubled) {
    const float diff = std::sqrt(std::max(sigma * sigma - kInitSigma * kInitSigma * 4, 0.01f));
    cv::Mat twice;
    cv::resize(f, twice, cv::Size(f.cols * 2, f.rows * 2), 0, 0, cv::INTER_LINEAR);
    cv::GaussianBlur(twice, out, cv::Size(), diff, diff);
    return out;
  }
  const float diff = std::sqrt(std::max(sigma * sigma - kInitSigma * kInitSigma, 0.01f));
  cv::GaussianBlur(f, out, cv::Size(), diff, diff);
  return out;
}

std::vector<std::vector<cv::Mat>> SiftGaussianPyramid(const cv::Mat& base, int octaves, int layers, int top,
                                                      double sigma) {
  std::vector<double> sig(static_cast<size_t>(layers + 3));
  sig[0] = sigma;
  const double k = std::pow(2., 1. / layers);
  for (int i = 1; i < layers + 3; i++) {
    const double prev = std::pow(k, double(i - 1)) * sigma, total = prev * k;
    sig[size_t(i)] = std::sqrt(total * total - prev * prev);
  }
  std::vector<std::vector<cv::Mat>> pyramid(static_cast<size_t>(octaves));
  for (int o = 0; o < octaves; ++o) {
    auto& level = pyramid[size_t(o)];
    const int last = o + 1 < octaves ? std::max(top, layers) : top;
    level.resize(static_cast<size_t>(last + 1));
    if (o == 0) {
      level[0] = base;
    } else {
      const cv::Mat& src = pyramid[size_t(o - 1)][size_t(layers)];
      cv::resize(src, level[0], cv::Size(src.cols / 2, src.rows / 2), 0, 0, cv::INTER_NEAREST);
    }
    for (int i = 1; i <= last; ++i)
      cv::GaussianBlur(level[size_t(i - 1)], level[size_t(i)], cv::Size(), sig[size_t(i)], sig[size_t(i)]);
  }
  return pyramid;
}

void UnpackSiftOctave(const cv::KeyPoint& k, int* octave, int* layer, float* scale) {
  *octave = k.octave & 255;
  *layer = (k.octave >> 8) & 255;
  *octave = *octave < 128 ? *octave : (-128 | *octave);
  *scale = *octave >= 0 ? 1.f / static_cast<float>(1 << *octave) : static_cast<float>(1 << -*octave);
}

}  // namespace rolamos
