#include "engine/keyframe_job.h"

#include <algorithm>

#include "util/cpu_time.h"

namespace rolamos {

void FollowedSample::Add(FollowedFrame f) {
  if (++seen_ % stride_ != 0) return;
  kept_.push_back(std::move(f));
  if (kept_.size() <= capacity_) return;
  // Those kept were the stride-th, 2 stride-th, ... frames: keep the 2 stride-th, 4 stride-th, ...
  size_t out = 0;
  for (size_t i = 1; i < kept_.size(); i += 2) kept_[out++] = std::move(kept_[i]);
  kept_.resize(out);
  stride_ *= 2;
}

std::vector<FollowedFrame> FollowedSample::Take() {
  std::vector<FollowedFrame> out = std::move(kept_);
  kept_.clear();
  seen_ = 0;
  stride_ = 1;
  return out;
}

KeyframeProducts RunKeyframeJob(const KeyframeJob& job, const KeyframeTools& tools) {
  KeyframeProducts out;
  CpuLaps cpu;
  // The spatio-temporal filter: the frame before (not blended itself) averaged in where the two
  // agree, then the bilateral filter. A keyframe right after another has no such frame: blending
  // averages the two already.
  if (job.blend) {
    cv::Mat image = job.frame->image;
    if (tools.temporal && job.before && !job.before->image.empty() && job.before->image.size() == image.size())
      image = tools.pre->Temporal(image, job.before->image, job.to_before);
    if (tools.bilateral) image = tools.pre->Bilateral(image);
    out.image = image;
  }
  out.filter_seconds = 1e-9 * cpu.Lap();
  out.features = tools.features(*job.frame);
  // Nothing reads a blended frame's unfiltered image after this (the patch blends the filtered
  // one): a patch's keyframes hold one image each until it is written, not two.
  if (job.blend) job.frame->image.release();
  cpu.Restart();  // the features are timed where they are found
  // Loop closures within the patch: the older keyframes under this one (their jobs ran before).
  // An earlier lane may lie further off than the guided search reaches: a loop candidate the
  // guided search does not link is searched over all the features the two may share, until one
  // such search fails (each costs a match of all against all); where one finds the lane, the
  // candidates after it are guided from the placement it implies.
  if (out.features && !out.features->empty()) {
    cv::Matx33d to_patch = job.to_patch;
    bool searched = false;
    for (const auto& older : job.older) {
      const KeyframeProducts& theirs = older.products.get();
      if (!theirs.features || theirs.features->empty()) continue;
      PatchFrame f;
      f.index = older.index;
      f.to_patch = older.to_patch;
      f.features = theirs.features;
      const bool wide = older.loop && !searched;
      cv::Matx33d placed = to_patch;
      if (auto link = LinkPair(job.index, *out.features, older.loop ? to_patch : job.to_patch, f, tools.fit,
                               wide ? job.frame->size : cv::Size(), &placed)) {
        out.loop_links.push_back(std::move(*link));
        to_patch = placed;
      } else {
        searched = searched || wide;
      }
    }
  }
  out.link_seconds = 1e-9 * cpu.Lap();
  if (!job.followed.empty()) out.between = FollowBack(job, tools);
  out.follow_seconds = 1e-9 * cpu.Lap();
  return out;
}

std::vector<FollowedBetween> FollowBack(const KeyframeJob& job, const KeyframeTools& tools) {
  std::vector<FollowedBetween> out;
  if (!job.track || !tools.tracker || job.points.empty()) return out;
  SharedWindows own;  // without the engine's: made once for all the frames
  SharedWindows* windows = job.windows ? job.windows.get() : &own;
  for (const FollowedFrame& f : job.followed) {
    if (!f.track || f.track->size != job.track->size) continue;
    // Where following put both: this keyframe's pixels -> the frame's.
    const cv::Matx33d guess = (job.followed_from_to_patch * f.to_before).inv() * job.to_patch;
    const TrackFlow flow = tools.tracker->Follow(*job.track, *f.track, job.points, guess, windows);
    std::vector<cv::Point2f> in_frame, in_key;
    flow.Kept(job.points, &in_frame, &in_key);
    const EgomotionResult e = EstimateEgomotion(in_frame, in_key, tools.K, tools.ego);
    if (!e.ok || !AssessSupport(e, job.track->size, tools.support).strong) continue;
    out.push_back({f.index, job.followed_from, job.index, f.to_before, e.H,
                   double(f.inliers) / std::max(1, f.inliers + e.inliers)});
  }
  return out;
}

}  // namespace rolamos
