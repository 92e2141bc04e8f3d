#include "engine/static_mask.h"

#include <algorithm>
#include <cstdio>

#include <opencv2/imgcodecs.hpp>  // the IMREAD_ flags only: util/codecs.h reads
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "util/codecs.h"

namespace rolamos {

bool StaticMaskOptions::IsValid(std::string* error) const {
  if (frames < 4 || min_frames < 4 || min_frames > frames || !(scale > 0.05 && scale <= 1) || !(min_ratio > 0 && min_ratio < 1) || !(min_edge > 0) ||
      !(grow >= 0 && grow < 0.2) || !(max_fraction > 0 && max_fraction <= 1)) {
    *error = "static mask settings are out of range (at least 4 frames, scale in (0.05, 1], ratio in (0, 1))";
    return false;
  }
  return true;
}

namespace {

cv::Mat GradientMagnitude(const cv::Mat& f) {
  cv::Mat gx, gy, mag;
  cv::Sobel(f, gx, CV_32F, 1, 0, 3, 0.125);
  cv::Sobel(f, gy, CV_32F, 0, 1, 3, 0.125);
  cv::magnitude(gx, gy, mag);
  return mag;
}

}  // namespace

StaticMask EstimateStaticMask(const std::vector<cv::Mat>& frames, const StaticMaskOptions& o) {
  StaticMask out;
  std::string error;
  if (!o.IsValid(&error)) Fail("static mask", error);
  if (static_cast<int>(frames.size()) < o.min_frames) {
    out.note = "too few frames (" + std::to_string(frames.size()) + ") to tell fixed overlays from the seafloor";
    out.conclusive = false;
    return out;
  }
  const cv::Size size = frames[0].size();
  cv::Mat sum, grad_sum;
  int n = 0;
  for (const auto& frame : frames) {
    if (frame.size() != size) continue;
    cv::Mat gray, small;
    if (frame.channels() == 3) cv::cvtColor(frame, gray, cv::COLOR_BGR2GRAY);
    else gray = frame;
    cv::resize(gray, small, cv::Size(), o.scale, o.scale, cv::INTER_AREA);
    small.convertTo(small, CV_32F);
    if (sum.empty()) {
      sum = cv::Mat::zeros(small.size(), CV_32F);
      grad_sum = cv::Mat::zeros(small.size(), CV_32F);
    }
    sum += small;
    grad_sum += GradientMagnitude(small);
    ++n;
  }
  if (n < o.min_frames) {
    out.note = "too few frames (" + std::to_string(n) + ") to tell fixed overlays from the seafloor";
    out.conclusive = false;
    return out;
  }
  const cv::Mat mean = sum / n, mean_grad = grad_sum / n;
  const cv::Mat grad_of_mean = GradientMagnitude(mean);
  cv::Mat ratio;
  cv::divide(grad_of_mean, cv::max(mean_grad, 1e-3), ratio);
  // Fixed edges: strong in the mean image, and as strong as in the frames themselves. Moving
  // texture keeps about 1/sqrt(n) of its edges in the mean, more by chance: the bar rises with
  // fewer frames.
  const double bar = std::max(o.min_ratio, 2.5 / std::sqrt(double(n)));
  cv::Mat fixed = (ratio > bar) & (grad_of_mean > o.min_edge);
  // The moving seafloor must average out for the test to mean anything: the typical textured
  // pixel (above the median of the frames' edge strength) must lose its edges in the mean.
  std::vector<float> g(mean_grad.begin<float>(), mean_grad.end<float>());
  std::nth_element(g.begin(), g.begin() + g.size() / 2, g.end());
  std::vector<float> r;
  for (int y = 0; y < ratio.rows; ++y)
    for (int x = 0; x < ratio.cols; ++x)
      if (mean_grad.at<float>(y, x) > g[g.size() / 2]) r.push_back(ratio.at<float>(y, x));
  double moving = 1.0;
  if (!r.empty()) {
    std::nth_element(r.begin(), r.begin() + r.size() / 2, r.end());
    moving = r[r.size() / 2];
  }
  if (!(moving < bar)) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "the seafloor hardly moves under these frames (edge ratio %.2f)", moving);
    out.note = buf;
    out.conclusive = false;
    return out;
  }
  // Overlays are marks of some size; single pixels are the chance residue of the average.
  cv::Mat labels, stats, centroids;
  const int count = cv::connectedComponentsWithStats(fixed, labels, stats, centroids, 8, CV_32S);
  for (int c = 1; c < count; ++c)
    if (stats.at<int>(c, cv::CC_STAT_AREA) < o.min_area_px) fixed.setTo(0, labels == c);
  // Close the gaps between a text's strokes, then grow over the blur and back to full size.
  const int close = std::max(1, static_cast<int>(std::lround(4 * o.scale * 4)));
  cv::morphologyEx(fixed, fixed, cv::MORPH_CLOSE,
                   cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * close + 1, 2 * close + 1)));
  cv::Mat full;
  cv::resize(fixed, full, size, 0, 0, cv::INTER_NEAREST);
  const int grow = std::max(2, static_cast<int>(std::lround(o.grow * size.width)));
  cv::dilate(full, full, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * grow + 1, 2 * grow + 1)));
  out.fraction = cv::countNonZero(full) / double(full.total());
  char buf[200];
  if (out.fraction > o.max_fraction) {
    std::snprintf(buf, sizeof buf, "%.0f %% of the frame looks fixed: taken for a still camera, no mask used",
                  100 * out.fraction);
    out.note = buf;
    out.fraction = 0;
    return out;
  }
  if (out.fraction == 0) {
    out.note = "no fixed overlay found";
    return out;
  }
  out.mask = full;
  out.note = "fixed overlay found";  // the caller says where and how much
  return out;
}

cv::Mat ReadStaticMask(const std::string& path, cv::Size frame) {
  cv::Mat m = ReadImageFile(path, cv::IMREAD_GRAYSCALE);
  if (m.empty()) Fail(path, "cannot be read as a mask image");
  if (m.size() != frame) cv::resize(m, m, frame, 0, 0, cv::INTER_NEAREST);
  return m > 0;
}

}  // namespace rolamos
