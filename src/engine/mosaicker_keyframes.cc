// Mosaicker's keyframes: when a frame becomes one, fitted against the recent ones, described,
// linked to older lanes, blended or only placed, and the frames followed between them.
#include "engine/mosaicker_impl.h"

namespace rolamos {

// Keyframes by predicted overlap: a frame is blended when it overlaps the last keyframe too
// little, when the next one is predicted to, when its registration is doubtful or did not come
// from following, or when the points followed have thinned out.
bool Mosaicker::Impl::WantsKeyframe(const Candidate& c, const cv::Matx33d& to_patch) const {
  const Key& key = keys.back();
  const double overlap = FootprintOverlap(to_patch, key.to_patch, frame_size);
  if (!c.tracked() || !c.support.strong) return true;
  // A keyframe that would only link (it overlaps the last blended one by blend_overlap or more)
  // is taken only with frames followed since the last keyframe: on video, not on stills at
  // 80 % overlap, where every other frame would be one for little gain (paper: 7 % slower).
  // A still left out of the patch image (still_blend_overlap) counts as blended here: else the
  // frame after it would be a keyframe only because the last blended one is two stills back.
  const bool only_links = WouldOnlyLink(to_patch, options.blend_overlap) ||
                          (key.still && !key.blended && overlap >= options.blend_overlap);
  if (overlap < options.keyframe_overlap &&
      (options.keyframe_overlap >= 1.0 || FollowedSinceKeyframe() || !only_links))
    return true;
  if (c.at.size() < std::max<size_t>(size_t(2 * support_options.strong_inliers), key.points.size() / 3)) return true;
  // The next frame, if the motion from the last one repeats.
  const cv::Matx33d next = to_patch * last.to_patch.inv() * to_patch;
  return FootprintOverlap(next, key.to_patch, frame_size) < options.keyframe_min_overlap;
}

// A new keyframe's placement fitted against the recent keyframes it overlaps besides the one it
// was followed from (each followed into it anew: independent measurements, so error does not
// add up from keyframe to keyframe). Returns the placement; `fitted` gets the links.
cv::Matx33d Mosaicker::Impl::FitToKeyframes(const PreparedFrame& p, const Candidate& c, std::vector<FrameLink>* fitted,
                                            int* frames_used) {
  const cv::Matx33d guess = c.to_patch;
  *fitted = c.Links(-1);
  for (auto& l : *fitted) l.a = -1;  // set by the caller
  *frames_used = 1;
  if (!options.patch_fit || !c.tracked() || keys.size() < 2) return guess;
  PatchPairs pairs;
  const Key& key = keys.back();
  for (size_t i = 0; i < c.ego.inlier_from.size(); ++i)
    pairs.Add(c.ego.inlier_from[i], key.to_patch, c.ego.inlier_to[i], key.index);
  int used = 0;
  for (auto it = keys.rbegin() + 1; it != keys.rend() && used < 2; ++it) {
    if (!it->frame || !it->frame->track) break;  // no longer kept: older ones are not either
    if (FootprintOverlap(guess, it->to_patch, frame_size) < 0.3) continue;
    const TrackFlow flow =
        tracker.Follow(*it->frame->track, *p.track, it->points, guess.inv() * it->to_patch, it->windows.get());
    int n = 0;
    for (size_t i = 0; i < it->points.size(); ++i) {
      if (!flow.ok[i]) continue;
      pairs.Add(flow.to[i], it->to_patch, it->points[i], it->index);
      ++n;
    }
    if (n >= 8) ++used;
  }
  if (used == 0) return guess;
  // Every round's cut the same (FitToPatch widens the first for its guided matches).
  const TrimmedFit trimmed = FitTrimmedHomography(pairs, guess, fit_options.inlier_px, 0.0);
  if (!trimmed.ok) return guess;
  const cv::Matx33d& H = trimmed.H;
  if (MaxCornerShift(H, guess, frame_size) > fit_options.max_correction_px ||
      !IsPlausibleMotion(last.to_patch.inv() * H, frame_size, support_options))
    return guess;
  *fitted = LinksByFrame(-1, pairs, trimmed.keep);  // a: set by the caller
  *frames_used = 1 + used;
  return H;
}

// An older keyframe is a loop closure's candidate when it overlaps the new one by this many times
// the overlap the recent ones need (PatchFitOptions::min_overlap).
constexpr double kLoopOverlap = 2.0;

size_t Mosaicker::Impl::FirstRecentKey(bool current) const {
  const size_t end = current ? keys.size() - 1 : keys.size();
  return end > size_t(fit_options.recent_frames) ? end - size_t(fit_options.recent_frames) : 0;
}

std::vector<std::pair<double, const Mosaicker::Impl::Key*>> Mosaicker::Impl::OlderUnder(const cv::Matx33d& to_patch,
                                                                                          bool current) const {
  std::vector<std::pair<double, const Key*>> under;
  for (size_t k = 0; k < FirstRecentKey(current); ++k) {
    if (!keys[k].described) continue;
    const double overlap = FootprintOverlap(to_patch, keys[k].to_patch, frame_size);
    if (overlap >= kLoopOverlap * fit_options.min_overlap) under.emplace_back(overlap, &keys[k]);
  }
  std::sort(under.begin(), under.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
  return under;
}

std::vector<OlderKeyframe> Mosaicker::Impl::LinkCandidates(const cv::Matx33d& to_patch, bool current) const {
  std::vector<OlderKeyframe> out;
  if (keys.empty()) return out;
  // The keyframe followed from is linked by the tracks already.
  const size_t end = current ? keys.size() - 1 : keys.size();
  const size_t recent = FirstRecentKey(current);
  for (size_t k = end; k-- > recent;) {
    if (static_cast<int>(out.size()) >= fit_options.max_frames) break;
    if (keys[k].described && FootprintOverlap(to_patch, keys[k].to_patch, frame_size) >= fit_options.min_overlap)
      out.push_back({keys[k].index, keys[k].to_patch, keys[k].products});
  }
  const auto under = OlderUnder(to_patch, current);
  for (size_t k = 0; k < under.size() && k < size_t(fit_options.max_loop_frames); ++k)
    out.push_back({under[k].second->index, under[k].second->to_patch, under[k].second->products, true});
  return out;
}

// Every keyframe's ground must be described for the global map, not every keyframe: on stills at
// 70 % overlap each frame is a keyframe, and features are the largest part of its cost. A keyframe
// followed with strong support is described when it has moved far enough from the last one that
// was; one placed any other way (the first of a patch, recovered, doubtful, the last) always is,
// as is one whose features were found already, or that rejected frames wait to be tried against.
bool Mosaicker::Impl::Describes(const PreparedFrame& p, const cv::Matx33d& to_patch, const Candidate* c,
                                bool still) const {
  if (!c || !c->tracked() || !c->support.strong || p.features || !pending.empty()) return true;
  double overlap = options.describe_overlap;
  if (still) {
    // The lane before under it: its loop links hold the lanes of a patch together.
    if (options.still_describe_overlap < 1.0 && !OlderUnder(to_patch, true).empty()) return true;
    overlap = std::min(overlap, options.still_describe_overlap);
  }
  if (shedding) overlap = std::min(overlap, shed_describe_overlap);
  if (overlap >= 1.0) return true;
  for (auto it = keys.rbegin(); it != keys.rend(); ++it)
    if (it->described) return FootprintOverlap(to_patch, it->to_patch, frame_size) < overlap;
  return true;
}

bool Mosaicker::Impl::WouldOnlyLink(const cv::Matx33d& to_patch, double overlap) const {
  for (auto it = keys.rbegin(); it != keys.rend(); ++it)
    if (it->blended) return FootprintOverlap(to_patch, it->to_patch, frame_size) >= overlap;
  return false;
}

// The patch image needs a keyframe about every 25 % of a frame (blend_overlap); the adjustment
// is held straighter by keyframes every 15 % (keyframe_overlap). A keyframe simply followed, with
// strong support, that the last blended one still covers enough of links and places only.
bool Mosaicker::Impl::Blends(const Candidate& c, const cv::Matx33d& to_patch) const {
  if (!c.tracked() || !c.support.strong || !pending.empty()) return true;
  return !WouldOnlyLink(to_patch, StillKeyframe(to_patch) ? std::min(options.blend_overlap, options.still_blend_overlap)
                                                          : options.blend_overlap);
}

// A keyframe into the working canvas and the lighting model.
void Mosaicker::Impl::AddToCanvas(const PreparedFrame& p, const cv::Matx33d& to_patch) {
  canvas->Add(p.image, *weights, to_patch);
  if (options.flat_field || options.water_colour) {
    const cv::Mat u = Usable();
    colour->Add(p.image, u.size() == p.image.size() ? u : cv::Mat());
  }
}

void Mosaicker::Impl::AddKeyframe(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch,
                                  const Candidate* c, std::vector<FrameLink> found, FrameRecord rec, bool current,
                                  bool blend) {
  Laps lap{this, {}};
  const bool still = current && StillKeyframe(to_patch);
  const bool described = Describes(*p, to_patch, c, still);
  if (!described) rec.described = false;
  // Its features are found by its job, or not at all (no job reads `ahead` before it is submitted).
  keyframed_now = true;
  if (described) wanted_now = true;
  else p->ahead.reset();
  if (blend) AddToCanvas(*p, to_patch);
  else rec.blended = false;
  lap(kCanvas);
  if (adjust_options.enabled)
    for (auto& l : found) links.push_back(Thin(std::move(l), adjust_options.max_pairs_per_link, frame_size));
  frames.push_back(std::move(rec));
  // The points it hands on: the tracks that reached it, topped up with corners where they thinned.
  Key key;
  key.index = frames.back().index;
  key.to_patch = to_patch;
  key.frame = p;
  key.described = described;
  key.blended = blend;
  key.still = still;
  if (c) {
    key.points = c->at;
    key.ids = c->ids;
  }
  const int points = still ? std::max(track_points, options.still_track_points) : track_points;
  const int wanted = points - static_cast<int>(key.points.size());
  if (wanted > points / 8)
    for (const auto& q : tracker.Corners(*p->track, key.points, wanted)) {
      key.points.push_back(q);
      key.ids.push_back(next_track++);
    }
  lap(kTracking);
  // Filtering, features and loop closures on the workers; the job keeps what it needs and
  // releases the unfiltered image when done: it is not read here once the job is submitted.
  keyframe_bytes += KeyframeBytes(*p, described, blend);  // until the patch is written
  KeyframeJob job;
  job.index = key.index;
  job.frame = p;
  job.blend = blend;
  // Read once the job runs, on its thread. A keyframe that only links is described coarsely (SIFT
  // without its doubled first octave), but not a still: its features are the global map's only
  // links to the lane beside it, and were most often found ahead already.
  if (!blend && !p->features && !still) p->coarse_features = true;
  if (current && last.frame && FollowedSinceKeyframe() && !p->features) p->followed_features = true;
  if (blend && current && last.frame && !last.blended && !last.frame->image.empty() &&
      last.frame->image.size() == p->image.size()) {
    job.before = last.frame;
    job.to_before = last.to_patch.inv() * to_patch;
  }
  job.to_patch = to_patch;
  if (adjust_options.enabled && described) job.older = LinkCandidates(to_patch, current);
  if (current) {
    // The frames followed since the keyframe before (not this one, when it was one of them).
    for (auto& f : followed_since_key.Take())
      if (f.index != key.index) job.followed.push_back(std::move(f));
    if (!job.followed.empty()) {
      // Followed from the keyframe before this one, the last in `keys` until this one goes in.
      job.track = p->track;
      job.points = key.points;
      job.windows = key.windows;
      job.followed_from = keys.back().index;
      job.followed_from_to_patch = keys.back().to_patch;
    }
  }
  KeyframeTools tools;
  tools.pre = &pre;
  tools.bilateral = options.bilateral;
  tools.temporal = options.temporal;
  if (described) tools.features = [this](PreparedFrame& f) { return FeaturesOf(f); };
  else tools.features = [](PreparedFrame&) { return std::shared_ptr<const Features>(); };
  tools.fit = fit_options;
  tools.tracker = &tracker;
  tools.K = K;
  tools.ego = ego_options;
  tools.support = support_options;
  // The task's state, this lambda with it, lives as long as the products' future (the patch):
  // the job is moved out and dropped when done, or it would hold its frames' images and
  // pyramids until the patch is written (500 MB more on 300 frames of video followed back).
  auto task = std::make_shared<std::packaged_task<KeyframeProducts()>>([this, job = std::move(job), tools]() mutable {
    const KeyframeJob done = std::move(job);
    KeyframeProducts out = RunKeyframeJob(done, tools);
    stage_ns[kFilter] += static_cast<long long>(1e9 * out.filter_seconds);
    stage_ns[kLoopLinks] += static_cast<long long>(1e9 * out.link_seconds);
    stage_ns[kTracking] += static_cast<long long>(1e9 * out.follow_seconds);
    return out;
  });
  key.products = task->get_future().share();
  keyframe_pool.Submit([task] { (*task)(); });
  if (!current && !keys.empty()) {
    key.frame.reset();
    keys.insert(keys.end() - 1, std::move(key));
  } else {
    keys.push_back(std::move(key));
    last = Placed{keys.back().index, to_patch, p, true, {}, blend, still};
  }
  // Keyframes behind the recent ones are not followed from again: their pyramids go, also from
  // the frame their job may still hold (it reads the image and features, never the pyramid).
  if (keys.size() > 3) {
    if (keys[keys.size() - 4].frame) keys[keys.size() - 4].frame->track.reset();
    keys[keys.size() - 4].frame.reset();
    keys[keys.size() - 4].windows.reset();
  }
  ++summary.stitched;
  ++summary.keyframes;
  summary.described += described;
  summary.blended += blend;
}

void Mosaicker::Impl::AddFollowed(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch, FrameRecord rec,
                                  std::vector<FrameLink> found) {
  rec.keyframe = false;
  rec.placed_from = keys.back().index;
  if (options.follow_back && p->track)
    followed_since_key.Add({rec.index, p->track, keys.back().to_patch.inv() * to_patch, rec.inliers});
  frames.push_back(std::move(rec));
  last = Placed{frames.back().index, to_patch, p, false, std::move(found)};
  ++summary.stitched;
}

void Mosaicker::Impl::PromoteLast() {
  if (!LastIsOpenPatchsNewest()) return;
  if (last.keyframe) {
    if (!last.blended) BlendLastKeyframe();
    return;
  }
  FrameRecord rec = frames.back();
  frames.pop_back();
  --summary.stitched;
  rec.keyframe.reset();
  rec.placed_from.reset();
  const Placed was = last;
  last.keyframe = true;  // no temporal term with itself
  last.blended = true;
  AddKeyframe(was.frame, was.to_patch, nullptr, was.links, std::move(rec));
}

// The patch's last keyframe, placed but not blended, is blended after all: nothing after it in
// this patch covers the part of its ground the last blended keyframe does not. Its features and
// links are the job's it had; the spatio-temporal filter has no frame before it here.
void Mosaicker::Impl::BlendLastKeyframe() {
  Key& key = keys.back();
  const std::shared_ptr<PreparedFrame> p = key.frame;
  if (key.index != last.index || !p || p->image.empty()) return;
  AddToCanvas(*p, key.to_patch);
  frames.back().blended.reset();
  key.blended = last.blended = true;
  keyframe_bytes += p->image.total() * p->image.elemSize();
  ++summary.blended;
  const KeyframeFuture linked = key.products;
  const bool bilateral = options.bilateral;
  auto task = std::make_shared<std::packaged_task<KeyframeProducts()>>([this, p, linked, bilateral] {
    KeyframeProducts out = linked.get();  // submitted before this one: running or done
    CpuLaps cpu;
    out.image = bilateral ? pre.Bilateral(p->image) : p->image;
    stage_ns[kFilter] += cpu.Lap();
    return out;
  });
  key.products = task->get_future().share();
  keyframe_pool.Submit([task] { (*task)(); });
}

// The share of a still's width (height) along its edges that may be left to its neighbours'
// edges when it is not blended.
constexpr double kStillMargin = 0.04;

bool Mosaicker::Impl::LastStillUncovered(const cv::Matx33d* next) const {
  if (!StillBlendRule() || !last.keyframe || last.blended || !last.still || keys.empty() ||
      keys.back().index != last.index)
    return false;
  std::vector<cv::Matx33d> to_blended;  // patch -> each covering frame
  if (next) to_blended.push_back(next->inv());
  for (auto it = keys.rbegin() + 1; it != keys.rend() && to_blended.size() < 4; ++it)
    if (it->blended) to_blended.push_back(it->to_patch.inv());
  // A grid over the frame but for a margin along its edges (kStillMargin): with the vehicle's
  // roll and sway, the stills before and after a still are offset from it sideways by a few
  // pixels, which no blended frame covers however many are blended along a lane's edge.
  const double w = frame_size.width - 1.0, h = frame_size.height - 1.0;
  const double mx = kStillMargin * w, my = kStillMargin * h;
  for (int gy = 0; gy <= 6; ++gy)
    for (int gx = 0; gx <= 6; ++gx) {
      const cv::Vec3d p = last.to_patch * cv::Vec3d(mx + (w - 2 * mx) * gx / 6, my + (h - 2 * my) * gy / 6, 1);
      bool covered = false;
      for (const auto& inv : to_blended) {
        const cv::Vec3d q = inv * p;
        const double x = q[0] / q[2], y = q[1] / q[2];
        if (q[2] > 0 && x >= 0 && y >= 0 && x <= w && y <= h) {
          covered = true;
          break;
        }
      }
      if (!covered) return true;
    }
  return false;
}

}  // namespace rolamos
