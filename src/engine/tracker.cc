#include "engine/tracker.h"

#include <algorithm>
#include <cmath>
#include <functional>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "engine/area_resize.h"
#include "engine/corner_peaks.h"
#include "engine/grey.h"
#include "engine/lucas_kanade.h"
#include "engine/motion_gate.h"
#include "engine/perspective_warp.h"
#include "rolamos/error.hpp"
#include "util/homography.h"

namespace rolamos {

bool TrackerOptions::IsValid(std::string* error) const {
  if (!(track_pixels >= 2e4 && track_pixels <= 1e8)) {
    *error = "tracking image size " + std::to_string(track_pixels) + " pixels is outside 2e4..1e8";
    return false;
  }
  if (!(codec_pixels >= 2e4 && codec_pixels <= 1e8)) {
    *error = "tracking image size for video " + std::to_string(codec_pixels) + " pixels is outside 2e4..1e8";
    return false;
  }
  const auto window_ok = [](int w) { return w >= 5 && w <= 61; };
  if (max_points < 30 || !window_ok(window) || !window_ok(halved_window) || !window_ok(quarter_window) || levels < 0 ||
      levels > 6) {
    *error = "tracker settings are out of range (points >= 30, windows 5..61, levels 0..6)";
    return false;
  }
  if (max_iterations < 1 || !(min_step_px > 0)) {
    *error = "Lucas-Kanade needs at least one step and a positive smallest step";
    return false;
  }
  if (!(max_fb_px > 0) || !(corner_quality > 0 && corner_quality < 1) ||
      !(normalize_sigma >= 0)) {
    *error = "tracker thresholds must be positive (corner quality below 1)";
    return false;
  }
  if (!(give_up_below >= 0 && give_up_below < 1)) {
    *error = "share of a sample a follow gives up below, " + std::to_string(give_up_below) + ", is outside 0..1";
    return false;
  }
  if (!(turn_deg >= 0 && turn_deg <= 180)) {
    *error = "tracking turn " + std::to_string(turn_deg) + " degrees is outside 0..180";
    return false;
  }
  if (!(turn_search_deg >= 0 && turn_search_deg <= 180) || !(turn_search_step_deg >= 1)) {
    *error = "turn search " + std::to_string(turn_search_deg) + " degrees in steps of " +
             std::to_string(turn_search_step_deg) + " is outside 0..180 in steps of 1 or more";
    return false;
  }
  return true;
}

double TrackerOptions::ScaleFor(cv::Size frame) const {
  // Exact 2 x 2 averages.
  double area = std::max(1.0, double(frame.area())), scale = 1.0;
  if (halve_once && area >= 0.4 * track_pixels) {
    scale = 0.5;
    area /= 4;
  }
  const double most = halve_once ? std::min(track_pixels, codec_pixels) : track_pixels;
  for (; area > most; area /= 4) scale /= 2;
  return scale;
}

bool TrackerOptions::CodecAtAQuarter(cv::Size frame) const { return halve_once && ScaleFor(frame) <= 0.25; }

int TrackerOptions::PointsFor(cv::Size frame) const { return CodecAtAQuarter(frame) ? 2 * max_points : max_points; }

int TrackerOptions::WindowFor(cv::Size frame) const {
  if (CodecAtAQuarter(frame)) return quarter_window;
  return ScaleFor(frame) < 1.0 ? halved_window : window;
}

namespace {

// Full-resolution pixel <-> tracking pixel: q = (p + 0.5) s - 0.5.
cv::Point2f ToTrack(cv::Point2f p, double s) {
  return {float((p.x + 0.5) * s - 0.5), float((p.y + 0.5) * s - 0.5)};
}
cv::Point2f ToFull(cv::Point2f q, double s) {
  return {float((q.x + 0.5) / s - 0.5), float((q.y + 0.5) / s - 0.5)};
}
cv::Matx33d ScaleMap(double s) {  // full -> tracking
  return cv::Matx33d(s, 0, 0.5 * (s - 1), 0, s, 0.5 * (s - 1), 0, 0, 1);
}

// The difference from the mean around each pixel, divided by the standard deviation around it
// (both smooth: computed at a quarter of the size), as 40 grey levels per standard deviation
// around 128. Smooth light (vignetting, the lights' cone, haze, a frame's exposure) goes with
// them. The local deviation is floored at half the frame's: flat areas are not lifted into noise.
cv::Mat LocalContrast(const cv::Mat& gray, double sigma) {
  cv::Mat f, small, mean, var;
  gray.convertTo(f, CV_32F);
  auto smooth = [&](const cv::Mat& in, cv::Mat& out) {
    cv::resize(in, small, cv::Size(), 0.25, 0.25, cv::INTER_AREA);
    cv::GaussianBlur(small, small, cv::Size(), sigma / 4);
    cv::resize(small, out, in.size(), 0, 0, cv::INTER_LINEAR);
  };
  smooth(f, mean);
  const cv::Mat detail = f - mean;
  cv::Mat squared = detail.mul(detail);
  const double frame_var = cv::mean(squared)[0];
  smooth(squared, var);
  cv::Mat sd;
  cv::sqrt(cv::max(var, std::max(1.0, 0.25 * frame_var)), sd);
  cv::Mat out;
  cv::Mat(detail / sd).convertTo(out, CV_8U, 40.0, 128.0);
  return out;
}

}  // namespace

void TrackFlow::Kept(const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* landed,
                     std::vector<cv::Point2f>* started, std::vector<size_t>* which) const {
  for (size_t i = 0; i < points.size() && i < ok.size(); ++i) {
    if (!ok[i]) continue;
    landed->push_back(to[i]);
    started->push_back(points[i]);
    if (which) which->push_back(i);
  }
}

FrameTracker::FrameTracker(const TrackerOptions& options) : options_(options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("tracker", error);
}

std::shared_ptr<const TrackFrame> FrameTracker::Prepare(const cv::Mat& frame, const cv::Mat& usable) const {
  auto t = std::make_shared<TrackFrame>();
  t->size = frame.size();
  t->scale = options_.ScaleFor(frame.size());
  cv::Mat gray;
  if (frame.channels() == 3) BgrToGrey(frame, gray);
  else if (frame.channels() == 4) cv::cvtColor(frame, gray, cv::COLOR_BGRA2GRAY);
  else gray = frame;
  if (t->scale < 1.0) {
    cv::Mat small;
    ResizeArea(gray, small, t->scale);
    gray = small;
  }
  if (options_.normalize_sigma > 0) gray = LocalContrast(gray, options_.normalize_sigma);
  const int window = options_.WindowFor(frame.size());
  cv::buildOpticalFlowPyramid(gray, t->pyramid, cv::Size(window, window), options_.levels, true);
  if (!usable.empty()) {
    cv::resize(usable, t->usable, gray.size(), 0, 0, cv::INTER_NEAREST);
    // A window over an overlay's edge follows the overlay: keep a window's half away.
    cv::erode(t->usable, t->usable, cv::Mat(), cv::Point(-1, -1), window / 2);
  }
  return t;
}

std::vector<cv::Point2f> FrameTracker::Corners(const TrackFrame& frame, const std::vector<cv::Point2f>& existing,
                                               int count) const {
  std::vector<cv::Point2f> out;
  if (frame.pyramid.empty()) return out;
  const cv::Mat& gray = frame.pyramid[0];
  const double s = frame.scale;
  // Shi-Tomasi's smaller eigenvalue, local maxima only, a window's half from the border.
  const int border = options_.WindowFor(frame.size) / 2 + 1;
  const std::vector<CornerPeak> peaks = CornerPeaks(gray, border, 1e-7f);
  // The scale: the 30th strongest local maximum.
  float reference = 0;
  if (!peaks.empty()) {
    std::vector<float> tops(peaks.size());
    for (size_t i = 0; i < peaks.size(); ++i) tops[i] = peaks[i].response;
    const size_t k = std::min<size_t>(29, tops.size() - 1);
    std::nth_element(tops.begin(), tops.begin() + long(k), tops.end(), std::greater<float>());
    reference = tops[k];
  }
  const float floor = float(std::max(options_.corner_quality * reference, 1e-7));
  // The frame in a grid of cells; each cell's best corners in turn, so points cover the frame.
  const int cols = 8, rows = 6;
  const float min_distance = float(std::max(gray.cols, gray.rows)) / 60.0f;
  cv::Mat taken(gray.size(), CV_8U, cv::Scalar(0));
  for (const auto& p : existing) cv::circle(taken, ToTrack(p, s), int(std::ceil(min_distance)), 255, -1);
  if (!frame.usable.empty()) taken.setTo(255, frame.usable == 0);
  std::vector<std::vector<std::pair<float, cv::Point>>> cells(size_t(cols * rows));
  for (const CornerPeak& p : peaks) {
    if (p.response < floor || taken.at<uchar>(p.y, p.x)) continue;
    const int cx = std::min(cols - 1, p.x * cols / gray.cols), cy = std::min(rows - 1, p.y * rows / gray.rows);
    cells[size_t(cy * cols + cx)].emplace_back(p.response, cv::Point(p.x, p.y));
  }
  for (auto& c : cells)
    std::sort(c.begin(), c.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<size_t> next(cells.size(), 0);
  for (bool any = true; any && static_cast<int>(out.size()) < count;) {
    any = false;
    for (size_t k = 0; k < cells.size() && static_cast<int>(out.size()) < count; ++k) {
      auto& c = cells[k];
      while (next[k] < c.size()) {
        const cv::Point q = c[next[k]++].second;
        if (taken.at<uchar>(q)) continue;
        cv::circle(taken, q, int(std::ceil(min_distance)), 255, -1);
        out.push_back(ToFull(cv::Point2f(q), s));
        any = true;
        break;
      }
    }
  }
  // Sub-pixel corner positions: the tracked point starts where the corner is.
  if (!out.empty()) {
    std::vector<cv::Point2f> q;
    for (const auto& p : out) q.push_back(ToTrack(p, s));
    cv::cornerSubPix(gray, q, cv::Size(3, 3), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 10, 0.03));
    for (size_t i = 0; i < q.size(); ++i) out[i] = ToFull(q[i], s);
  }
  return out;
}

const LucasKanadeTemplates& SharedWindows::Get(
    const std::function<std::shared_ptr<const LucasKanadeTemplates>()>& make) {
  std::call_once(made_, [&] { windows_ = make(); });
  return *windows_;
}

TrackFlow FrameTracker::Follow(const TrackFrame& from, const TrackFrame& to, const std::vector<cv::Point2f>& points,
                               const cv::Matx33d& guess, SharedWindows* windows, bool may_give_up) const {
  TrackFlow flow;
  flow.to.resize(points.size());
  flow.ok.assign(points.size(), 0);
  if (points.empty() || from.pyramid.empty() || to.pyramid.empty()) return flow;
  const double s = from.scale;
  std::vector<cv::Point2f> a, b;
  a.reserve(points.size());
  b.reserve(points.size());
  const cv::Matx33d G = ScaleMap(to.scale) * guess * ScaleMap(s).inv();
  for (const auto& p : points) {
    a.push_back(ToTrack(p, s));
    b.push_back(cv::Point2f(ApplyHomography(G, a.back())));
  }
  std::vector<uchar> forward(points.size(), 0);
  const cv::Size win(options_.WindowFor(from.size), options_.WindowFor(from.size));
  const cv::TermCriteria until(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, options_.max_iterations,
                               options_.min_step_px);
  constexpr double kMinEigen = 1e-4;
  // Turned: followed in `to` warped back onto `from` (where the guess puts every point in place).
  std::vector<cv::Mat> turned;
  const std::vector<cv::Mat>* target = &to.pyramid;
  if (options_.turn_deg > 0 &&
      std::abs(MotionOf(G, from.pyramid[0].size()).rotation) * 180 / CV_PI > options_.turn_deg) {
    cv::Mat warped;
    WarpPerspectiveLinear(to.pyramid[0], warped, G, from.pyramid[0].size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                          cv::BORDER_REPLICATE);
    cv::buildOpticalFlowPyramid(warped, turned, win, options_.levels, true);
    target = &turned;
    b = a;
  }
  const cv::Size t = to.pyramid[0].size();
  // The points `which` (indices into `points`) followed forward, then back from where they landed.
  auto follow = [&](const std::vector<int>& which) {
    // All of them: no index list (OpenCV's fallback would gather and scatter every point).
    const std::vector<int>* only = which.size() == points.size() ? nullptr : &which;
    if (windows) {
      const LucasKanadeTemplates& made =
          windows->Get([&] { return PrepareLucasKanade(from.pyramid, a, win, options_.levels, kMinEigen); });
      FollowLucasKanade(made, from.pyramid, *target, a, &b, &forward, until, only);
    } else {
      FollowLucasKanade(from.pyramid, *target, a, &b, &forward, win, options_.levels, until, kMinEigen, only);
    }
    // Back only from where the forward pass landed on usable ground: the others are lost anyway.
    std::vector<size_t> landed;
    std::vector<cv::Point2f> from_b, to_a;
    for (int w : which) {
      const size_t i = size_t(w);
      // Where the point landed in `to` (`b` is in the target's pixels, which are `from`'s if turned).
      const cv::Point2f q = target == &turned ? cv::Point2f(ApplyHomography(G, b[i])) : b[i];
      flow.to[i] = ToFull(q, to.scale);
      const bool inside = q.x >= 0 && q.y >= 0 && q.x <= t.width - 1 && q.y <= t.height - 1;
      const bool overlay = inside && !to.usable.empty() && !to.usable.at<uchar>(cv::Point(q));
      if (!forward[i] || !inside || overlay) continue;
      landed.push_back(i);
      from_b.push_back(b[i]);
      to_a.push_back(a[i]);
    }
    if (landed.empty()) return;
    std::vector<cv::Point2f> back = to_a;
    std::vector<uchar> backward;
    FollowLucasKanade(*target, from.pyramid, from_b, &back, &backward, win, options_.levels, until, kMinEigen);
    for (size_t k = 0; k < landed.size(); ++k) {
      const float dx = back[k].x - to_a[k].x, dy = back[k].y - to_a[k].y;
      flow.ok[landed[k]] = backward[k] && dx * dx + dy * dy <= options_.max_fb_px * options_.max_fb_px;
      flow.followed += flow.ok[landed[k]];
    }
  };
  // A sample first when asked: most of a failing start's cost is saved, a holding one's is not raised.
  constexpr size_t kEvery = 4, kMinSample = 32;
  const bool sampled =
      may_give_up && options_.give_up_below > 0 && (points.size() + kEvery - 1) / kEvery >= kMinSample;
  std::vector<int> sample, rest;
  for (size_t i = 0; i < points.size(); ++i) (sampled && i % kEvery == 0 ? sample : rest).push_back(int(i));
  if (sampled) {
    follow(sample);
    if (flow.followed < options_.give_up_below * double(sample.size())) {
      flow.cut_short = true;
      return flow;
    }
  }
  follow(rest);
  return flow;
}

namespace {

// Phase correlation of two frames' pyramid levels: `from`'s seen through a guess (full-resolution
// pixels), on `to`'s grid, against `to`'s.
class LevelCorrelation {
 public:
  // The coarsest level of `to` with at least `min_cols` pixels across (the pyramids interleave
  // images and their derivatives); false when the pyramids are empty.
  bool Open(const TrackFrame& from, const TrackFrame& to, int min_cols) {
    if (from.pyramid.empty() || to.pyramid.empty()) return false;
    size_t level = 0;
    while (2 * (level + 1) < to.pyramid.size() && to.pyramid[2 * (level + 1)].cols >= min_cols) ++level;
    b_ = to.pyramid[2 * level];
    a_ = from.pyramid[2 * std::min(level, from.pyramid.size() / 2 - 1)];
    sa_ = from.scale / double(1 << level);
    sb_ = to.scale / double(1 << level);
    b_.convertTo(fb_, CV_32F);
    cv::createHanningWindow(window_, b_.size(), CV_32F);
    return true;
  }
  int cols() const { return b_.cols; }
  // The shift (full-resolution pixels) that best aligns `from` seen through `turn * guess` with
  // `to`, `turn` a rotation of `deg` about the level's centre; its peak in *response.
  cv::Matx33d Shift(const cv::Matx33d& guess, double deg, double* response) {
    const cv::Matx33d turn = Turn(deg);
    const cv::Matx33d G = turn * ScaleMap(sb_) * guess * ScaleMap(sa_).inv();
    WarpPerspectiveLinear(a_, warped_, G, b_.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    warped_.convertTo(fa_, CV_32F);
    const cv::Point2d shift = cv::phaseCorrelate(fa_, fb_, window_, response);
    const double k = 1.0 / sb_;  // tracking pixels at this level -> full-resolution pixels
    const cv::Matx33d T(1, 0, shift.x * k, 0, 1, shift.y * k, 0, 0, 1);
    if (deg == 0) return T * guess;
    return T * ScaleMap(sb_).inv() * turn * ScaleMap(sb_) * guess;
  }

 private:
  cv::Matx33d Turn(double deg) const {
    if (deg == 0) return cv::Matx33d::eye();
    const double t = deg * CV_PI / 180, c = std::cos(t), s = std::sin(t);
    const double x = (b_.cols - 1) * 0.5, y = (b_.rows - 1) * 0.5;
    return cv::Matx33d(c, -s, x - c * x + s * y, s, c, y - s * x - c * y, 0, 0, 1);
  }
  cv::Mat a_, b_, fb_, window_, warped_, fa_;
  double sa_ = 1, sb_ = 1;
};

}  // namespace

cv::Matx33d FrameTracker::CoarseShift(const TrackFrame& from, const TrackFrame& to, const cv::Matx33d& guess,
                                      double* response) const {
  *response = 0;
  LevelCorrelation level;
  if (!level.Open(from, to, 48)) return guess;
  return level.Shift(guess, 0, response);
}

cv::Matx33d FrameTracker::CoarseTurn(const TrackFrame& from, const TrackFrame& to, const cv::Matx33d& guess,
                                     double* response) const {
  *response = 0;
  const double range = options_.turn_search_deg, step = options_.turn_search_step_deg;
  LevelCorrelation level;
  // At 50 x 38 (a video's frames followed at half size) any turn correlated as well as none.
  constexpr int kMinCols = 96;
  if (range <= 0 || !level.Open(from, to, kMinCols) || level.cols() < kMinCols) return guess;
  cv::Matx33d best = guess;
  double best_deg = 0;
  auto consider = [&](double deg) {
    double r = 0;
    const cv::Matx33d at = level.Shift(guess, deg, &r);
    if (r <= *response) return;
    *response = r;
    best = at;
    best_deg = deg;
  };
  for (double deg = step; deg <= range + 1e-9; deg += step) {
    consider(deg);
    consider(-deg);
  }
  if (*response > 0) {
    const double around = best_deg;
    consider(around - step / 2);
    consider(around + step / 2);
  }
  return best;
}

}  // namespace rolamos
