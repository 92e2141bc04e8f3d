#include "objects/object_crop.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {

cv::Rect ObjectBox(const cv::Mat& bgr, double margin) {
  constexpr int kSide = 128;  // saliency is judged at this size
  cv::Mat small, lab;
  cv::resize(bgr, small, cv::Size(kSide, kSide), 0, 0, cv::INTER_AREA);
  small.convertTo(lab, CV_32F, 1.0 / 255);
  cv::cvtColor(lab, lab, cv::COLOR_BGR2Lab);
  cv::Mat background;
  cv::GaussianBlur(lab, background, cv::Size(), 16);
  cv::Mat diff = lab - background, d2;
  cv::multiply(diff, diff, d2);
  cv::Mat saliency = cv::Mat::zeros(kSide, kSide, CV_32F);
  std::vector<cv::Mat> ch;
  cv::split(d2, ch);
  for (const auto& c : ch) saliency += c;
  cv::sqrt(saliency, saliency);
  cv::GaussianBlur(saliency, saliency, cv::Size(), 2);
  // The object is near the centre: weigh saliency by a broad prior there.
  cv::Mat prior(kSide, kSide, CV_32F);
  const float s = 0.3f * kSide, c = (kSide - 1) / 2.0f;
  for (int y = 0; y < kSide; ++y)
    for (int x = 0; x < kSide; ++x)
      prior.at<float>(y, x) = std::exp(-((x - c) * (x - c) + (y - c) * (y - c)) / (2 * s * s));
  cv::Mat weighted = saliency.mul(prior);
  double peak = 0;
  cv::Point at;
  cv::minMaxLoc(weighted, nullptr, &peak, nullptr, &at);
  cv::Rect box(kSide / 4, kSide / 4, kSide / 2, kSide / 2);  // nothing stands out: the centre
  if (peak > 0) {
    // The blob: connected pixels around the peak above 40 % of its saliency.
    const cv::Mat mask = saliency > 0.4 * saliency.at<float>(at);
    cv::Mat labels;
    cv::connectedComponents(mask, labels, 8, CV_32S);
    const int id = labels.at<int>(at);
    if (id > 0) box = cv::boundingRect(labels == id);
  }
  const double side = std::max(16.0, margin * std::max(box.width, box.height));
  const double cx = box.x + box.width / 2.0, cy = box.y + box.height / 2.0;
  const double fx = double(bgr.cols) / kSide, fy = double(bgr.rows) / kSide;
  return cv::Rect(static_cast<int>(std::lround((cx - side / 2) * fx)), static_cast<int>(std::lround((cy - side / 2) * fy)),
                  std::max(1, static_cast<int>(std::lround(side * fx))), std::max(1, static_cast<int>(std::lround(side * fy))));
}

cv::Mat ObjectCrop(const cv::Mat& bgr, double margin) {
  const cv::Rect box = ObjectBox(bgr, margin);
  const cv::Rect inside = box & cv::Rect(0, 0, bgr.cols, bgr.rows);
  if (inside.empty()) return bgr.clone();
  cv::Mat out;
  cv::copyMakeBorder(bgr(inside), out, inside.y - box.y, box.br().y - inside.br().y, inside.x - box.x,
                     box.br().x - inside.br().x, cv::BORDER_REPLICATE);
  return out;
}

}  // namespace rolamos
