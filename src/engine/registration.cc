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
      !(ratio > 0.3 && ratio < 1) || !(inlier_px > 0) || !(max_correction_px > 0) ||
      !(loop_drift >= 0 && loop_drift <= 1)) {
    *error = "patch fit settings are out of range";
    return false;
  }
  return true;
}

namespace {

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
    const cv::Point2d q = ApplyHomography(a_to_b, a.points[i]);
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

void VerifiedMatch::Inliers(std::vector<cv::Point2f>* a, std::vector<cv::Point2f>* b) const {
  for (size_t i = 0; i < inlier.size(); ++i)
    if (inlier[i]) {
      a->push_back(matches.from[i]);
      b->push_back(matches.to[i]);
    }
}

VerifiedMatch VerifyByHomography(Matches m, int min_inliers) {
  VerifiedMatch v;
  v.matches = std::move(m);
  if (static_cast<int>(v.matches.from.size()) < std::max(min_inliers, 4)) return v;
  const cv::Mat H = cv::findHomography(v.matches.from, v.matches.to, cv::RANSAC, 3.0, v.inlier, 2000, 0.999);
  int count = 0;
  for (uchar x : v.inlier) count += x;
  if (H.empty() || count < min_inliers) return v;
  v.inliers = count;
  v.H = cv::Matx33d(H);
  return v;
}

VerifiedMatch MatchVerified(const Features& a, const Features& b, const FeatureOptions& options, int min_inliers) {
  return VerifyByHomography(MatchFeatures(a, b, options), min_inliers);
}

namespace {

// How far a loop link found over all features may differ from the placements in scale, turn and
// shear: a degraded lane's chain shears by up to 0.16 against the lane before over 30 stills
// (small-degraded, seed 37), while what RANSAC fits to chance matches is off by 0.3 or more.
constexpr double kLoopDistortion = 0.25;

// Whether `found` (frame -> older) is where the placements put the frame, within `drift` of the
// frame's diagonal at its centre, and the same motion otherwise (kLoopDistortion).
bool NearPrediction(const cv::Matx33d& found, const cv::Matx33d& predicted, cv::Size size, double drift) {
  const cv::Point2d c((size.width - 1) / 2.0, (size.height - 1) / 2.0);
  const cv::Point2d a = ApplyHomography(found, c), b = ApplyHomography(predicted, c);
  if (!(std::hypot(a.x - b.x, a.y - b.y) <= drift * std::hypot(size.width, size.height))) return false;
  // The found motion undone by the predicted one: near the identity, up to the shift.
  const cv::Matx22d J = HomographyJacobian(predicted.inv() * found, c);
  return std::abs(J(0, 0) - 1) < kLoopDistortion && std::abs(J(1, 1) - 1) < kLoopDistortion &&
         std::abs(J(0, 1)) < kLoopDistortion && std::abs(J(1, 0)) < kLoopDistortion;
}

// The features of `f` whose points `to_other` maps within `margin` pixels of a frame of `size`.
Features WithinFrame(const Features& f, const cv::Matx33d& to_other, cv::Size size, double margin) {
  Features out;
  out.norm = f.norm;
  std::vector<int> rows;
  for (size_t i = 0; i < f.points.size(); ++i) {
    const cv::Point2d q = ApplyHomography(to_other, f.points[i]);
    if (q.x >= -margin && q.y >= -margin && q.x <= size.width - 1 + margin && q.y <= size.height - 1 + margin) {
      rows.push_back(static_cast<int>(i));
      out.points.push_back(f.points[i]);
    }
  }
  out.descriptors.create(static_cast<int>(rows.size()), f.descriptors.cols, f.descriptors.type());
  for (size_t r = 0; r < rows.size(); ++r) f.descriptors.row(rows[r]).copyTo(out.descriptors.row(static_cast<int>(r)));
  return out;
}

}  // namespace

std::optional<FrameLink> LinkPair(int index, const Features& frame, const cv::Matx33d& to_patch,
                                 const PatchFrame& older, const PatchFitOptions& o, cv::Size size,
                                 cv::Matx33d* placed) {
  if (!older.features) return std::nullopt;
  const auto link_of = [&](const VerifiedMatch& v) {
    FrameLink l;
    l.a = index;
    l.b = older.index;
    v.Inliers(&l.in_a, &l.in_b);
    return l;
  };
  const cv::Matx33d predicted = older.to_patch.inv() * to_patch;
  const VerifiedMatch guided = VerifyByHomography(MatchGuided(frame, *older.features, predicted, o.loop_radius, o.ratio), 20);
  if (guided.inliers) return link_of(guided);
  if (!(o.loop_drift > 0) || size.empty()) return std::nullopt;
  // Along a lane the chain drifts, and the lane before may lie further off than the guided
  // search reaches: a degraded survey's lanes drift a hundred pixels apart before they close.
  // Matched over all their features where the two may overlap, the frames tell where they
  // meet; the guided match then looks again from there.
  const double drift = o.loop_drift * std::hypot(size.width, size.height);
  const VerifiedMatch coarse = MatchVerified(WithinFrame(frame, predicted, size, drift),
                                             WithinFrame(*older.features, predicted.inv(), size, drift), FeatureOptions(), 20);
  if (!coarse.inliers || !NearPrediction(coarse.H, predicted, size, o.loop_drift)) return std::nullopt;
  const VerifiedMatch fine = VerifyByHomography(MatchGuided(frame, *older.features, coarse.H, o.search_radius, o.ratio), 20);
  if (!fine.inliers) return std::nullopt;
  if (placed) *placed = older.to_patch * coarse.H;
  return link_of(fine);
}

void PatchPairs::Add(cv::Point2f p, const cv::Matx33d& other_to_patch, cv::Point2f q, int who) {
  const cv::Point2d d = ApplyHomography(other_to_patch, q);
  in_frame.push_back(p);
  in_patch.emplace_back(static_cast<float>(d.x), static_cast<float>(d.y));
  in_other.push_back(q);
  other.push_back(who);
}

TrimmedFit FitTrimmedHomography(const PatchPairs& pairs, const cv::Matx33d& guess, double inlier_px,
                                double first_cut_px) {
  TrimmedFit fit;
  fit.H = guess;
  fit.keep.assign(pairs.size(), 1);
  if (pairs.size() < 12) return fit;
  for (int round = 0; round < 3; ++round) {
    std::vector<double> res(pairs.size());
    for (size_t i = 0; i < pairs.size(); ++i)
      res[i] = cv::norm(ApplyHomography(fit.H, pairs.in_frame[i]) - cv::Point2d(pairs.in_patch[i]));
    std::vector<double> sorted = res;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double cut = std::max(inlier_px, 3.0 * sorted[sorted.size() / 2]);
    std::vector<cv::Point2f> a, b;
    for (size_t i = 0; i < pairs.size(); ++i) {
      fit.keep[i] = res[i] <= (round == 0 ? std::max(cut, first_cut_px) : cut);
      if (!fit.keep[i]) continue;
      a.push_back(pairs.in_frame[i]);
      b.push_back(pairs.in_patch[i]);
    }
    if (a.size() < 12) return fit;
    const cv::Mat refined = cv::findHomography(a, b, 0);
    if (refined.empty()) return fit;
    fit.H = cv::Matx33d(refined);
    fit.H *= 1.0 / fit.H(2, 2);
    fit.inliers = static_cast<int>(a.size());
  }
  fit.ok = true;
  return fit;
}

std::vector<FrameLink> LinksByFrame(int index, const PatchPairs& pairs, const std::vector<uchar>& keep) {
  std::map<int, FrameLink> by_frame;
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (!keep[i]) continue;
    FrameLink& l = by_frame[pairs.other[i]];
    l.a = index;
    l.b = pairs.other[i];
    l.in_a.push_back(pairs.in_frame[i]);
    l.in_b.push_back(pairs.in_other[i]);
  }
  std::vector<FrameLink> links;
  for (auto& [who, l] : by_frame)
    if (l.in_a.size() >= 8) links.push_back(std::move(l));
  return links;
}

PatchFit FitToPatch(int index, const Features& frame, cv::Size size, const cv::Matx33d& guess,
                    const PatchFrame& previous, const std::vector<cv::Point2f>& from_prev,
                    const std::vector<cv::Point2f>& to_prev, const std::vector<PatchFrame>& patch,
                    const PatchFitOptions& o) {
  PatchFit fit;
  fit.to_patch = guess;
  PatchPairs pairs;
  for (size_t i = 0; i < from_prev.size(); ++i) pairs.Add(from_prev[i], previous.to_patch, to_prev[i], previous.index);
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
    for (size_t i = 0; i < m.from.size(); ++i) pairs.Add(m.from[i], f->to_patch, m.to[i], f->index);
    ++fit.frames;
  }
  if (pairs.size() < 12) return fit;
  // Guided matches may lie up to the search radius from the guess: the first round keeps them.
  const TrimmedFit trimmed = FitTrimmedHomography(pairs, guess, o.inlier_px, o.search_radius);
  fit.inliers = trimmed.inliers;
  if (!trimmed.ok) return fit;
  fit.correction_px = MaxCornerShift(trimmed.H, guess, size);
  if (!(fit.correction_px <= o.max_correction_px)) return fit;
  fit.to_patch = trimmed.H;
  fit.ok = true;
  // The surviving pairs, by patch frame: the links the patch adjustment uses when it closes.
  fit.links = LinksByFrame(index, pairs, trimmed.keep);
  return fit;
}

}  // namespace rolamos
