#include "engine/patch_adjustment.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>

#include "util/homography.h"

namespace rolamos {

bool PatchAdjustmentOptions::IsValid(std::string* error) const {
  if (!solver.IsValid(error)) return false;
  if (max_pairs_per_link < 8 || !(max_rms_px > 0)) {
    *error = "patch adjustment needs at least 8 pairs a link and a positive error bound";
    return false;
  }
  if (!(robust_loss_px >= 0 && robust_loss_px <= 10)) {
    *error = "the patch adjustment's robust loss " + std::to_string(robust_loss_px) + " px must be in [0, 10]";
    return false;
  }
  return true;
}

FrameLink Thin(FrameLink link, int max_pairs, cv::Size frame) {
  if (static_cast<int>(link.in_a.size()) <= max_pairs) return link;
  constexpr int kCells = 6;
  std::vector<std::vector<size_t>> cells(kCells * kCells);
  for (size_t i = 0; i < link.in_a.size(); ++i) {
    const int cx = std::clamp(int(link.in_a[i].x * kCells / std::max(1, frame.width)), 0, kCells - 1);
    const int cy = std::clamp(int(link.in_a[i].y * kCells / std::max(1, frame.height)), 0, kCells - 1);
    cells[size_t(cy * kCells + cx)].push_back(i);
  }
  FrameLink out;
  out.a = link.a;
  out.b = link.b;
  for (size_t round = 0; static_cast<int>(out.in_a.size()) < max_pairs; ++round) {
    bool any = false;
    for (const auto& c : cells) {
      if (round >= c.size()) continue;
      any = true;
      out.in_a.push_back(link.in_a[c[round]]);
      out.in_b.push_back(link.in_b[c[round]]);
      if (static_cast<int>(out.in_a.size()) >= max_pairs) break;
    }
    if (!any) break;
  }
  return out;
}

namespace {

// The lowest frame drawn at its own resolution where that gains this much, by at most kMaxFinerGain
// (altitude jitter and tilt stay under 1.1).
constexpr double kFinerGain = 1.25;
constexpr double kMaxFinerGain = 3.0;
// The adjusted frames' bounding box, at most this many times the online one's area (before the
// lowest frame's gain): a larger one is no flat ground seen through a pinhole camera.
constexpr double kMaxGrowth = 16.0;

int Root(std::vector<int>& parent, int i) {
  while (parent[size_t(i)] != i) i = parent[size_t(i)] = parent[size_t(parent[size_t(i)])];
  return i;
}

// Frames whose links do not reach the first frame's would float free in the solve (a frame
// registered against the patch image, the tracks it handed on): each such group is tied to the
// frame before it by its online placement, the measurement that put it there (a 4 x 4 grid of
// points through the two online homographies). Returns the ties added.
int TieUnlinked(const std::vector<cv::Matx33d>& online, cv::Size frame, std::vector<PlaneLink>* links) {
  const int n = static_cast<int>(online.size());
  std::vector<int> parent(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) parent[size_t(i)] = i;
  for (const auto& l : *links) parent[size_t(Root(parent, l.a))] = Root(parent, l.b);
  int ties = 0;
  for (int i = 1; i < n; ++i) {
    if (Root(parent, i) == Root(parent, i - 1)) continue;
    PlaneLink tie;
    tie.a = i;
    tie.b = i - 1;
    const cv::Matx33d H = online[size_t(i - 1)].inv() * online[size_t(i)];
    for (int gy = 0; gy < 4; ++gy)
      for (int gx = 0; gx < 4; ++gx) {
        const cv::Point2d p((gx + 0.5) * frame.width / 4, (gy + 0.5) * frame.height / 4);
        const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
        tie.in_a.emplace_back(p);
        tie.in_b.emplace_back(q[0] / q[2], q[1] / q[2]);
      }
    links->push_back(std::move(tie));
    parent[size_t(Root(parent, i))] = Root(parent, i - 1);
    ++ties;
  }
  return ties;
}

// The poses over every pair at the focal length `f`: under the solver's Huber loss, then under
// a Cauchy loss from robust_loss_px. Poses the focal length's search solved already start the
// Cauchy solve themselves (one full solve, as before this loss, not two: 1.6-5 % of the engine's
// CPU); the online chain's first go through the Huber one, so that links it left pixels off are not discounted before the poses
// come near them. The statistics are the last solve's, from where the first started.
PlaneAdjustment SolveOverEveryPair(std::vector<PlanePose>* poses, double* f, cv::Size frame,
                                   const std::vector<PlaneLink>& links, bool solved,
                                   const PatchAdjustmentOptions& o) {
  PlaneAdjustmentOptions huber = o.solver;
  huber.refine_focal = false;
  PlaneAdjustment first;
  if (!solved || o.robust_loss_px <= 0) {
    first = AdjustPlanePoses(poses, f, frame, links, 0, {}, {}, huber);
    if (!first.ok || o.robust_loss_px <= 0) return first;
  }
  PlaneAdjustmentOptions cauchy = huber;
  cauchy.loss = "cauchy";
  cauchy.loss_px = o.robust_loss_px;
  std::vector<PlanePose> trial = *poses;
  PlaneAdjustment last = AdjustPlanePoses(&trial, f, frame, links, 0, {}, {}, cauchy);
  if (!last.ok) return solved ? AdjustPlanePoses(poses, f, frame, links, 0, {}, {}, huber) : first;
  *poses = trial;
  if (!solved) last.initial_rms_px = first.initial_rms_px;
  return last;
}

}  // namespace

PatchAdjustment AdjustPatch(const std::vector<int>& indices, const std::vector<cv::Matx33d>& online,
                            const std::vector<FrameLink>& links, double focal, cv::Size frame,
                            const PatchAdjustmentOptions& o) {
  PatchAdjustment out;
  out.frame_to_patch = online;
  if (!o.enabled) {
    out.miss = PatchAdjustment::Miss::kOff;
    out.note = "off";
    return out;
  }
  if (indices.size() < 3) {
    out.miss = PatchAdjustment::Miss::kTooFewFrames;
    out.note = "fewer than three frames";
    return out;
  }
  std::map<int, int> slot;
  for (size_t i = 0; i < indices.size(); ++i) slot[indices[i]] = static_cast<int>(i);
  const cv::Matx33d K = CameraMatrix(focal, frame);
  // Start: level cameras where the online placements put the frames; the first frame is the
  // reference (its pixels are the plane's at the start).
  std::vector<PlanePose> poses(indices.size());
  for (size_t i = 0; i < indices.size(); ++i)
    poses[i] = i == 0 ? ReferencePose(K) : LevelPoseFromHomography(online[i], K, frame);
  // The links at most max_pairs_per_link pairs each; for the focal length, at most kFocalPairs.
  std::vector<PlaneLink> plane_links, focal_links;
  for (const auto& l : links) {
    auto a = slot.find(l.a), b = slot.find(l.b);
    if (a == slot.end() || b == slot.end() || l.in_a.size() < 8) continue;
    auto thinned = [&](int max_pairs) {
      const FrameLink thin = Thin(l, max_pairs, frame);
      PlaneLink p;
      p.a = a->second;
      p.b = b->second;
      p.in_a = thin.in_a;
      p.in_b = thin.in_b;
      return p;
    };
    plane_links.push_back(thinned(o.max_pairs_per_link));
    if (o.solver.refine_focal) focal_links.push_back(thinned(PatchAdjustmentOptions::kFocalPairs));
  }
  // Every frame must be tied to the others, or its pose is free: a frame or group no link joins
  // to the rest (the closing frame after a rejected one, a frame placed against the patch image)
  // is held to the frame before it by its online placement.
  out.ties = TieUnlinked(online, frame, &plane_links);
  double f = focal;
  bool searched = false;  // the poses come from the focal length's search, not the online chain
  if (o.solver.refine_focal) {
    // The focal length, with the poses, from the thinned links: where the attitudes hardly change
    // it is barely observable and the solve creeps along it, at a twelfth of the residuals. The
    // poses found start the solve over every pair, which holds the focal length.
    TieUnlinked(online, frame, &focal_links);
    PlaneAdjustmentOptions search = o.solver;
    search.rounds = 1;  // links found false are the full solve's to judge
    std::vector<PlanePose> trial = poses;
    searched = AdjustPlanePoses(&trial, &f, frame, focal_links, 0, {}, {}, search).ok;
    if (searched) poses = trial;
    else f = focal;
  }
  out.stats = SolveOverEveryPair(&poses, &f, frame, plane_links, searched, o);
  if (!out.stats.ok) {
    out.miss = PatchAdjustment::Miss::kFailed;
    out.note = "adjustment failed: " + out.stats.message;
    return out;
  }
  if (!(out.stats.final_rms_px <= o.max_rms_px)) {
    char note[96];
    std::snprintf(note, sizeof note, "transfer error %.2f px after adjustment, more than %.2f", out.stats.final_rms_px,
                  o.max_rms_px);
    out.miss = PatchAdjustment::Miss::kMisfit;
    out.note = note;
    return out;
  }
  // The first camera's altitude made one plane pixel one frame pixel at the focal length it started
  // with; at the one found, the patch would be drawn at focal / f of the frames' resolution (skerki6,
  // 411 -> 781 px: at 0.53, three quarters of its pixels lost). The whole scene is scaled (poses'
  // centres and the plane alike: every frame sees the same), so the first frame is at its own
  // resolution again.
  for (auto& p : poses) p.centre *= f / focal;
  // Frames held still by a burned-in overlay alone (open water in a live run, before its mask was
  // found) fit a plane seen through a far shorter lens, and were drawn over 3 Gpx (59,729 x
  // 51,010 for 30 frames of 1292 x 964). Ground the online chain drew on a few frames' area does
  // not grow a hundredfold in the adjustment.
  const cv::Matx33d Kf = CameraMatrix(f, frame);
  double drawn = 0, online_drawn = 0;
  {
    cv::Rect2d a, b;
    for (size_t i = 0; i < indices.size(); ++i) {
      a |= WarpedBounds(FrameToPlane(poses[i], Kf), frame);
      b |= WarpedBounds(online[i], frame);
    }
    drawn = a.area();
    online_drawn = b.area();
  }
  if (!(drawn <= kMaxGrowth * online_drawn)) {
    char note[128];
    std::snprintf(note, sizeof note, "the adjusted frames cover %.0f times the online ones' area", drawn / online_drawn);
    out.miss = PatchAdjustment::Miss::kMisfit;
    out.note = note;
    return out;
  }
  // A frame is drawn at its altitude over f: the first one at its own resolution, a lower one
  // smaller. A vehicle coming down onto the seafloor sees it best in its lowest frames, which
  // were drawn at a third of their size from three times the altitude. Where the lowest frame
  // would gain a quarter or more, the scene is scaled once more so that it is at its own
  // resolution (at most three times; the patch image grows with it). The online placements'
  // scale drifts by up to 30 % over a long patch (video-800-lights), the adjusted ones' does not.
  double lowest = std::numeric_limits<double>::max();
  for (const auto& p : poses) lowest = std::min(lowest, -p.centre[2]);
  if (const double finer = f / lowest; finer >= kFinerGain && std::isfinite(finer))
    for (auto& p : poses) p.centre *= std::min(finer, kMaxFinerGain);
  out.poses = poses;
  out.focal = f;
  for (size_t i = 0; i < indices.size(); ++i) out.frame_to_patch[i] = FrameToPlane(poses[i], Kf);
  out.used = true;
  return out;
}

}  // namespace rolamos
