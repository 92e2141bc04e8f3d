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
  const cv::Rect target = extent_.empty() ? needed : (extent_ | needed);
  // Grow with room on the sides that grew (a frame's size, or a quarter of the canvas), so a
  // patch is copied a few times, not at every frame. Near the budget the room shrinks to fit.
  int room_x = std::max(needed.width, target.width / 4), room_y = std::max(needed.height, target.height / 4);
  cv::Rect grown = target;
  for (int attempt = 0; attempt < 8; ++attempt) {
    const bool left = extent_.empty() || needed.x < extent_.x;
    const bool up = extent_.empty() || needed.y < extent_.y;
    const bool right = extent_.empty() || needed.br().x > extent_.br().x;
    const bool down = extent_.empty() || needed.br().y > extent_.br().y;
    grown = cv::Rect(cv::Point(target.x - (left ? room_x : 0), target.y - (up ? room_y : 0)),
                     cv::Point(target.br().x + (right ? room_x : 0), target.br().y + (down ? room_y : 0)));
    if (static_cast<long long>(grown.width) * grown.height <= budget_) break;
    room_x /= 2;
    room_y /= 2;
    grown = target;
  }
  cv::Mat sum = cv::Mat::zeros(grown.size(), CV_32FC3), weight = cv::Mat::zeros(grown.size(), CV_32F);
  if (!extent_.empty()) {
    const cv::Rect at(extent_.tl() - grown.tl(), extent_.size());
    sum_.copyTo(sum(at));
    weight_.copyTo(weight(at));
  }
  sum_ = sum;
  weight_ = weight;
  extent_ = grown;
}

void PatchCanvas::Add(const cv::Mat& frame, const cv::Mat& weights, const cv::Matx33d& H) {
  const cv::Rect roi = Enclosing(FrameBounds(H, frame.size()));
  GrowTo(roi);
  data_ = data_.empty() ? roi : (data_ | roi);
  // Warp into the ROI only: frame -> ROI pixel = T(-roi.tl) * H.
  const cv::Matx33d T(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1);
  const cv::Mat M(T * H);
  cv::Mat warped, warped_w;
  // Pixels repeat past the frame edge (never mixed with black); the weights fade there.
  cv::warpPerspective(frame, warped, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  cv::warpPerspective(weights, warped_w, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  const cv::Rect at(roi.tl() - extent_.tl(), roi.size());
  cv::Mat s = sum_(at), w = weight_(at);
  cv::parallel_for_(cv::Range(0, roi.height), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const cv::Vec3b* px = warped.ptr<cv::Vec3b>(y);
      const float* wt = warped_w.ptr<float>(y);
      cv::Vec3f* acc = s.ptr<cv::Vec3f>(y);
      float* wsum = w.ptr<float>(y);
      for (int x = 0; x < roi.width; ++x) {
        const float a = wt[x];
        if (a <= 0.f) continue;
        acc[x][0] += a * px[x][0];
        acc[x][1] += a * px[x][1];
        acc[x][2] += a * px[x][2];
        wsum[x] += a;
      }
    }
  });
}

cv::Mat PatchCanvas::Render(const cv::Rect& patch_rect) const {
  cv::Mat out = cv::Mat::zeros(patch_rect.size(), CV_8UC4);
  const cv::Rect inside = patch_rect & extent_;
  if (inside.empty()) return out;
  const cv::Rect src(inside.tl() - extent_.tl(), inside.size());
  const cv::Point at = inside.tl() - patch_rect.tl();
  // Blended colour where any frame weighed in, alpha 255 there; elsewhere all zero (no data,
  // not black data: the alpha says so).
  cv::parallel_for_(cv::Range(0, src.height), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const cv::Vec3f* s = sum_.ptr<cv::Vec3f>(src.y + y) + src.x;
      const float* w = weight_.ptr<float>(src.y + y) + src.x;
      cv::Vec4b* o = out.ptr<cv::Vec4b>(at.y + y) + at.x;
      for (int x = 0; x < src.width; ++x) {
        if (w[x] <= kAlphaCut) continue;
        const float k = 1.0f / w[x];
        o[x] = cv::Vec4b(cv::saturate_cast<uchar>(s[x][0] * k), cv::saturate_cast<uchar>(s[x][1] * k),
                         cv::saturate_cast<uchar>(s[x][2] * k), 255);
      }
    }
  });
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
