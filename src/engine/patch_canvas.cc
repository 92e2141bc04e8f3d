#include "engine/patch_canvas.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {

cv::Rect2d PatchCanvas::FrameBounds(const cv::Matx33d& H, cv::Size frame) {
  std::vector<cv::Point2d> c{{-0.5, -0.5}, {frame.width - 0.5, -0.5},
                             {frame.width - 0.5, frame.height - 0.5}, {-0.5, frame.height - 0.5}},
      w;
  cv::perspectiveTransform(c, w, cv::Mat(H));
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const auto& p : w) {
    x0 = std::min(x0, p.x);
    y0 = std::min(y0, p.y);
    x1 = std::max(x1, p.x);
    y1 = std::max(y1, p.y);
  }
  return cv::Rect2d(x0, y0, x1 - x0, y1 - y0);
}

namespace {

cv::Rect Enclosing(const cv::Rect2d& r) {
  const int x0 = static_cast<int>(std::floor(r.x)), y0 = static_cast<int>(std::floor(r.y));
  const int x1 = static_cast<int>(std::ceil(r.x + r.width)), y1 = static_cast<int>(std::ceil(r.y + r.height));
  return cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
}

}  // namespace

bool PatchCanvas::Fits(const cv::Rect2d& bounds) const {
  if (!std::isfinite(bounds.x) || !std::isfinite(bounds.width) || bounds.width > 1e8 ||
      bounds.height > 1e8)
    return false;
  const cv::Rect need = data_.empty() ? Enclosing(bounds) : (data_ | Enclosing(bounds));
  return static_cast<long long>(need.width) * need.height <= budget_;
}

void PatchCanvas::GrowTo(const cv::Rect& needed) {
  if (!extent_.empty() && (extent_ & needed) == needed) return;
  cv::Rect target = extent_.empty() ? needed : (extent_ | needed);
  // Grow with slack so a patch is not copied at every frame, but never past the budget.
  const int sx = target.width / 4, sy = target.height / 4;
  cv::Rect slack(target.x - (needed.x < extent_.x || extent_.empty() ? sx : 0),
                 target.y - (needed.y < extent_.y || extent_.empty() ? sy : 0), 0, 0);
  slack.width = target.x + target.width + sx - slack.x;
  slack.height = target.y + target.height + sy - slack.y;
  if (static_cast<long long>(slack.width) * slack.height <= budget_) target = slack;
  cv::Mat sum = cv::Mat::zeros(target.size(), CV_32FC3), weight = cv::Mat::zeros(target.size(), CV_32F);
  if (!extent_.empty()) {
    const cv::Rect at(extent_.tl() - target.tl(), extent_.size());
    sum_.copyTo(sum(at));
    weight_.copyTo(weight(at));
  }
  sum_ = sum;
  weight_ = weight;
  extent_ = target;
}

void PatchCanvas::Add(const cv::Mat& frame, const cv::Mat& weights, const cv::Matx33d& H) {
  const cv::Rect roi = Enclosing(FrameBounds(H, frame.size()));
  GrowTo(roi);
  data_ = data_.empty() ? roi : (data_ | roi);
  // Warp into the ROI only: frame -> ROI pixel = T(-roi.tl) * H.
  const cv::Matx33d T(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1);
  const cv::Mat M(T * H);
  cv::Mat f32, wf, warped_w;
  frame.convertTo(f32, CV_32FC3);
  std::vector<cv::Mat> ch;
  cv::split(f32, ch);
  for (auto& c : ch) c = c.mul(weights);
  cv::merge(ch, wf);
  cv::Mat warped;
  cv::warpPerspective(wf, warped, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  cv::warpPerspective(weights, warped_w, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  const cv::Rect at(roi.tl() - extent_.tl(), roi.size());
  cv::Mat s = sum_(at), w = weight_(at);
  s += warped;
  w += warped_w;
}

cv::Mat PatchCanvas::Render(const cv::Rect& patch_rect) const {
  cv::Mat out = cv::Mat::zeros(patch_rect.size(), CV_8UC4);
  const cv::Rect inside = patch_rect & extent_;
  if (inside.empty()) return out;
  const cv::Rect src(inside.tl() - extent_.tl(), inside.size());
  cv::Mat w = weight_(src), s = sum_(src);
  cv::Mat safe = cv::max(w, 1e-12);
  std::vector<cv::Mat> ch;
  cv::split(s, ch);
  for (auto& c : ch) cv::divide(c, safe, c);
  // Alpha: full where any frame weighed in (edges of the warped frames fade in over a pixel).
  cv::Mat alpha = w > kAlphaCut;
  ch.push_back(cv::Mat());
  alpha.convertTo(ch.back(), CV_32F);
  cv::Mat bgra;
  cv::merge(ch, bgra);
  cv::Mat dst = out(cv::Rect(inside.tl() - patch_rect.tl(), inside.size()));
  bgra.convertTo(dst, CV_8UC4);
  // Colour under alpha 0 stays 0 (no data, not black data: the alpha says so).
  dst.setTo(cv::Scalar::all(0), alpha == 0);
  return out;
}

void PatchCanvas::ViewFromFrame(const cv::Matx33d& H, cv::Size frame, double scale, cv::Mat* gray,
                                cv::Mat* mask) const {
  const cv::Size out(std::max(8, static_cast<int>(frame.width * scale)),
                     std::max(8, static_cast<int>(frame.height * scale)));
  // out pixel -> frame pixel -> patch -> canvas pixel.
  const double s = 1.0 / scale;
  const cv::Matx33d S(s, 0, 0.5 * (s - 1), 0, s, 0.5 * (s - 1), 0, 0, 1);
  const cv::Matx33d T(1, 0, -extent_.x, 0, 1, -extent_.y, 0, 0, 1);
  const cv::Mat M(T * H * S);
  cv::Mat sum_view, w_view;
  cv::warpPerspective(sum_, sum_view, M, out, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  cv::warpPerspective(weight_, w_view, M, out, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  std::vector<cv::Mat> ch;
  cv::split(sum_view, ch);
  cv::Mat safe = cv::max(w_view, 1e-12);
  cv::Mat g = (0.114 * ch[0] + 0.587 * ch[1] + 0.299 * ch[2]);
  cv::divide(g, safe, g);
  g.convertTo(*gray, CV_8U);
  *mask = w_view > kAlphaCut * 4;
}

}  // namespace rolamos
