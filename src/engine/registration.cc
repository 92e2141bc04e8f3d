#include "engine/registration.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_map>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "util/homography.h"

namespace rolamos {

bool SupportOptions::IsValid(std::string* error) const {
  if (strong_inliers < 8 || !(min_spread >= 0 && min_spread < 1) || !(max_scale_change > 1) ||
      !(max_anisotropy > 1) || !(max_perspective > 0)) {
    *error = "registration support thresholds are out of range (inliers >= 8, spread in [0, 1), "
             "scale and anisotropy limits > 1)";
    return false;
  }
  return true;
}

bool PatchFitOptions::IsValid(std::string* error) const {
  if (max_frames < 0 || !(min_overlap > 0 && min_overlap < 1) || !(search_radius > 0) ||
      !(ratio > 0.3 && ratio < 1) || !(inlier_px > 0) || !(max_correction_px > 0)) {
    *error = "patch fit settings are out of range";
    return false;
  }
  return true;
}

namespace {

cv::Point2d Apply(const cv::Matx33d& H, cv::Point2d p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
  return {q[0] / q[2], q[1] / q[2]};
}

std::vector<cv::Point2f> Corners(cv::Size s) {
  return {{0, 0}, {s.width - 1.0f, 0}, {s.width - 1.0f, s.height - 1.0f}, {0, s.height - 1.0f}};
}

}  // namespace

Support AssessSupport(const EgomotionResult& r, cv::Size frame, const SupportOptions& o) {
  Support s;
  if (!r.ok) {
    s.weakness = r.failure.empty() ? "not registered" : r.failure;
    return s;
  }
  s.inliers = r.inliers;
  if (r.inlier_from.size() >= 3) {
    std::vector<cv::Point2f> hull;
    cv::convexHull(r.inlier_from, hull);
    s.spread = cv::contourArea(hull) / std::max(1.0, double(frame.area()));
  }
  s.conditioned = IsPlausibleMotion(r.H, frame, o);
  if (s.inliers < o.strong_inliers) s.weakness = "few_inliers";
  else if (s.spread < o.min_spread) s.weakness = "clustered_inliers";
  else if (!s.conditioned) s.weakness = "implausible_homography";
  s.strong = s.weakness.empty();
  return s;
}

bool IsPlausibleMotion(const cv::Matx33d& H, cv::Size frame, const SupportOptions& o) {
  // A camera over a roughly flat seafloor: no mirror, scale and shear within bounds, and the
  // projective terms changing the scale across the frame only a little.
  const cv::Point2d c((frame.width - 1) / 2.0, (frame.height - 1) / 2.0);
  const cv::Matx22d J = HomographyJacobian(H, c);
  cv::Mat w;
  cv::SVD::compute(cv::Mat(J), w, cv::SVD::NO_UV);
  const double s1 = w.at<double>(0), s2 = w.at<double>(1);
  const double det = cv::determinant(J);
  double min_det = std::numeric_limits<double>::max(), max_det = 0;
  for (const auto& p : Corners(frame)) {
    const double d = cv::determinant(HomographyJacobian(H, p));
    min_det = std::min(min_det, d);
    max_det = std::max(max_det, d);
  }
  const bool finite = std::isfinite(s1) && std::isfinite(s2) && s2 > 1e-9;
  return finite && det > 0 && min_det > 0 && s1 < o.max_scale_change && s2 > 1.0 / o.max_scale_change &&
         s1 / s2 < o.max_anisotropy && std::sqrt(max_det / min_det) - 1.0 < o.max_perspective;
}

Matches MatchGuided(const Features& a, const Features& b, const cv::Matx33d& a_to_b, double radius,
                    double ratio) {
  Matches out;
  if (a.empty() || b.empty() || a.descriptors.type() != b.descriptors.type() || a.norm != b.norm)
    return out;
  // b's points in a grid of radius-sized cells.
  const double cell = radius;
  auto key = [](int cx, int cy) { return (int64_t(cx) << 32) ^ uint32_t(cy); };
  std::unordered_map<int64_t, std::vector<int>> grid;
  for (size_t j = 0; j < b.points.size(); ++j)
    grid[key(int(std::floor(b.points[j].x / cell)), int(std::floor(b.points[j].y / cell)))].push_back(int(j));
  const double r2 = radius * radius;
  std::vector<int> best_a(b.points.size(), -1);
  std::vector<double> best_d(b.points.size(), std::numeric_limits<double>::max());
  std::vector<int> match_of(a.points.size(), -1);
  for (size_t i = 0; i < a.points.size(); ++i) {
    const cv::Point2d q = Apply(a_to_b, a.points[i]);
    if (!std::isfinite(q.x) || !std::isfinite(q.y)) continue;
    const int cx = int(std::floor(q.x / cell)), cy = int(std::floor(q.y / cell));
    double d1 = std::numeric_limits<double>::max(), d2 = d1;
    int j1 = -1;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        auto it = grid.find(key(cx + dx, cy + dy));
        if (it == grid.end()) continue;
        for (int j : it->second) {
          const double ex = b.points[size_t(j)].x - q.x, ey = b.points[size_t(j)].y - q.y;
          if (ex * ex + ey * ey > r2) continue;
          const double d = DescriptorDistance(a, int(i), b, j);
          if (d < d1) {
            d2 = d1;
            d1 = d;
            j1 = j;
          } else if (d < d2) {
            d2 = d;
          }
        }
      }
    if (j1 < 0 || !(d1 < ratio * d2 || d2 == std::numeric_limits<double>::max())) continue;
    match_of[i] = j1;
    if (d1 < best_d[size_t(j1)]) {
      best_d[size_t(j1)] = d1;
      best_a[size_t(j1)] = int(i);
    }
  }
  // One to one: each of b's features keeps the a that resembles it most.
  for (size_t i = 0; i < a.points.size(); ++i) {
    const int j = match_of[i];
    if (j < 0 || best_a[size_t(j)] != int(i)) continue;
    out.from.push_back(a.points[i]);
    out.to.push_back(b.points[size_t(j)]);
  }
  return out;
}

double FootprintOverlap(const cv::Matx33d& a_to_patch, const cv::Matx33d& b_to_patch, cv::Size size) {
  std::vector<cv::Point2f> pa, pb, inter;
  cv::perspectiveTransform(Corners(size), pa, cv::Mat(a_to_patch));
  cv::perspectiveTransform(Corners(size), pb, cv::Mat(b_to_patch));
  const double area = std::abs(cv::contourArea(pa));
  if (!(area > 1)) return 0;
  // Both are convex (a homography of a plane seen from above keeps the frame convex).
  if (!cv::isContourConvex(pa) || !cv::isContourConvex(pb)) return 0;
  const float common = cv::intersectConvexConvex(pa, pb, inter, true);
  return std::max(0.0, double(common)) / area;
}

std::optional<FrameLink> LinkPair(int index, const Features& frame, const cv::Matx33d& to_patch,
                                 const PatchFrame& older, const PatchFitOptions& o) {
  if (!older.features) return std::nullopt;
  const Matches m = MatchGuided(frame, *older.features, older.to_patch.inv() * to_patch, o.loop_radius, o.ratio);
  if (m.from.size() < 20) return std::nullopt;
  std::vector<uchar> inlier;
  const cv::Mat H = cv::findHomography(m.from, m.to, cv::RANSAC, 3.0, inlier, 2000, 0.999);
  if (H.empty()) return std::nullopt;
  FrameLink l;
  l.a = index;
  l.b = older.index;
  for (size_t i = 0; i < inlier.size(); ++i)
    if (inlier[i]) {
      l.in_a.push_back(m.from[i]);
      l.in_b.push_back(m.to[i]);
    }
  if (l.in_a.size() < 20) return std::nullopt;
  return l;
}

std::vector<FrameLink> LinkOlderFrames(int index, const Features& frame, cv::Size size,
                                       const cv::Matx33d& to_patch, const std::vector<PatchFrame>& patch,
                                       const PatchFitOptions& o) {
  std::vector<FrameLink> out;
  if (patch.size() <= size_t(o.recent_frames)) return out;
  std::vector<std::pair<double, const PatchFrame*>> under;
  for (size_t k = 0; k + size_t(o.recent_frames) < patch.size(); ++k) {
    const PatchFrame& f = patch[k];
    if (!f.features) continue;
    const double overlap = FootprintOverlap(to_patch, f.to_patch, size);
    if (overlap >= 2 * o.min_overlap) under.emplace_back(overlap, &f);
  }
  std::sort(under.begin(), under.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
  for (const auto& [overlap, f] : under) {
    if (static_cast<int>(out.size()) >= o.max_loop_frames) break;
    if (auto l = LinkPair(index, frame, to_patch, *f, o)) out.push_back(std::move(*l));
  }
  return out;
}

PatchFit FitToPatch(int index, const Features& frame, cv::Size size, const cv::Matx33d& guess,
                    const PatchFrame& previous, const std::vector<cv::Point2f>& from_prev,
                    const std::vector<cv::Point2f>& to_prev, const std::vector<PatchFrame>& patch,
                    const PatchFitOptions& o) {
  PatchFit fit;
  fit.to_patch = guess;
  std::vector<cv::Point2f> src, dst, theirs;
  std::vector<int> owner;  // which patch frame each pair comes from
  auto add = [&](const cv::Point2f& p, const cv::Matx33d& H, const cv::Point2f& q, int who) {
    const cv::Point2d d = Apply(H, q);
    src.push_back(p);
    dst.emplace_back(static_cast<float>(d.x), static_cast<float>(d.y));
    theirs.push_back(q);
    owner.push_back(who);
  };
  for (size_t i = 0; i < from_prev.size(); ++i) add(from_prev[i], previous.to_patch, to_prev[i], previous.index);
  fit.frames = from_prev.empty() ? 0 : 1;
  // The other recent patch frames under the new one, most overlap first.
  std::vector<std::pair<double, const PatchFrame*>> under;
  const size_t first_recent = patch.size() > size_t(o.recent_frames) ? patch.size() - size_t(o.recent_frames) : 0;
  for (size_t k = first_recent; k < patch.size(); ++k) {
    const PatchFrame& f = patch[k];
    if (f.index == previous.index || !f.features) continue;
    const double overlap = FootprintOverlap(guess, f.to_patch, size);
    if (overlap >= o.min_overlap) under.emplace_back(overlap, &f);
  }
  std::sort(under.begin(), under.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
  if (static_cast<int>(under.size()) > o.max_frames) under.resize(static_cast<size_t>(o.max_frames));
  for (const auto& [overlap, f] : under) {
    const Matches m = MatchGuided(frame, *f->features, f->to_patch.inv() * guess, o.search_radius, o.ratio);
    if (m.from.size() < 8) continue;
    for (size_t i = 0; i < m.from.size(); ++i) add(m.from[i], f->to_patch, m.to[i], f->index);
    ++fit.frames;
  }
  if (src.size() < 12) return fit;
  // Least squares with outliers trimmed: the guided matches lie near the guess already, so a
  // robust start is the guess itself.
  cv::Matx33d H = guess;
  std::vector<uchar> keep(src.size(), 1);
  for (int round = 0; round < 3; ++round) {
    std::vector<double> res(src.size());
    for (size_t i = 0; i < src.size(); ++i) res[i] = cv::norm(Apply(H, src[i]) - cv::Point2d(dst[i]));
    std::vector<double> sorted = res;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double cut = std::max(o.inlier_px, 3.0 * sorted[sorted.size() / 2]);
    std::vector<cv::Point2f> a, b;
    for (size_t i = 0; i < src.size(); ++i) {
      keep[i] = res[i] <= (round == 0 ? std::max(cut, o.search_radius) : cut);
      if (!keep[i]) continue;
      a.push_back(src[i]);
      b.push_back(dst[i]);
    }
    if (a.size() < 12) return fit;
    const cv::Mat refined = cv::findHomography(a, b, 0);
    if (refined.empty()) return fit;
    H = cv::Matx33d(refined);
    H *= 1.0 / H(2, 2);
    fit.inliers = static_cast<int>(a.size());
  }
  fit.correction_px = MaxCornerShift(H, guess, size);
  if (!(fit.correction_px <= o.max_correction_px)) return fit;
  fit.to_patch = H;
  fit.ok = true;
  // The surviving pairs, by patch frame: the links the patch adjustment uses when it closes.
  std::map<int, FrameLink> by_frame;
  for (size_t i = 0; i < src.size(); ++i) {
    if (!keep[i]) continue;
    FrameLink& l = by_frame[owner[i]];
    l.a = index;
    l.b = owner[i];
    l.in_a.push_back(src[i]);
    l.in_b.push_back(theirs[i]);
  }
  for (auto& [who, l] : by_frame)
    if (l.in_a.size() >= 8) fit.links.push_back(std::move(l));
  return fit;
}

}  // namespace rolamos
