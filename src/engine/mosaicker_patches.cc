// Mosaicker's patches: opened, closed (pixel budget, lost tracking, a thin overlap), broken where
// tracking breaks, and dropped when a patch of its own would be a tile of water.
#include "engine/mosaicker_impl.h"

namespace rolamos {

namespace {

// The working canvas (refinement and recovery against the patch) at half resolution: a quarter
// of the blending work; the patch image is blended at full resolution when it closes.
constexpr double kWorkingScale = 0.5;

}  // namespace

void Mosaicker::Impl::StartPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport& r,
                                 const std::optional<PatchLink>& join) {
  canvas = std::make_unique<PatchCanvas>(options.PixelBudget(frame_size), kWorkingScale);
  patch_id = next_patch_id++;
  frames.clear();
  keys.clear();
  links.clear();
  keyframe_bytes = 0;
  link = join;
  opened_in_loss = r.index == 0 || last_rejected == r.index - 1;
  gate->Reset();
  last = Placed{};
  r.started_patch = true;
  r.continues = join.has_value();
  r.status = "stitched";
  r.patch_id = patch_id;
  r.keyframe = true;
  AddKeyframe(p, cv::Matx33d::eye(), nullptr, {}, RecordOf(r, cv::Matx33d::eye()));
  lost = 0;
}

void Mosaicker::Impl::ClosePatch(const std::string& why, const std::optional<ClosingFrame>& closing) {
  if (!canvas || frames.empty()) {
    canvas.reset();
    return;
  }
  if (IsolatedPatch(why)) return DropIsolatedPatch();
  if (!closing) PromoteLast();
  else if (LastStillUncovered(nullptr)) BlendLastKeyframe();  // the closing frame is the next patch's
  auto waiting = std::move(pending);
  for (auto& w : waiting) w.thin_overlap.reset();  // placements in the patch that closes
  std::vector<RejectedFrame> carried;
  for (const auto& w : waiting)
    for (auto it = rejected.begin(); it != rejected.end(); ++it)
      if (it->index == w.report.index) {
        carried.push_back(*it);
        rejected.erase(it);
        break;
      }
  PatchJob job;
  job.id = patch_id;
  job.next_id = next_patch_id;
  job.closed_by = why;
  job.frame_size = frame_size;
  job.pixel_budget = options.PixelBudget(frame_size);
  job.focal = K(0, 0);
  job.camera = K;
  job.frames = std::move(frames);
  summary.rejected_frames.insert(summary.rejected_frames.end(), rejected.begin(), rejected.end());
  job.rejected = std::move(rejected);
  job.link = link;
  for (const auto& k : keys) job.products.emplace_back(k.index, k.products);
  job.links = std::move(links);
  job.closing = closing;
  job.adjust = adjust_options;
  job.weights = weights;
  if (options.flat_field || options.water_colour) job.colour = colour->Correction(frame_size);
  job.exposure = options.exposure;
  writer.Submit(std::move(job));
  ++summary.patches;
  ForgetPatch();
  pending = std::move(waiting);
  rejected = std::move(carried);
}

void Mosaicker::Impl::ForgetPatch() {
  canvas.reset();
  frames.clear();
  keys.clear();
  links.clear();
  followed_since_key.Clear();
  keyframe_bytes = 0;
}

bool Mosaicker::Impl::IsolatedPatch(const std::string& why) const {
  if (frames.size() != 1 || link || !opened_in_loss) return false;
  const int first = frames.front().index;
  // The run's first frame only when tracking was then lost: two frames that do not register
  // leave the first mapped.
  if (first == 0 && why != "lost_tracking") return false;
  if (why == "end") return true;  // the run's last frames: nothing after it to join it
  if (why != "lost_tracking") return false;
  return std::any_of(rejected.begin(), rejected.end(), [&](const RejectedFrame& f) { return f.index > first; });
}

void Mosaicker::Impl::DropIsolatedPatch() {
  const FrameRecord f = frames.front();
  --summary.stitched;
  --summary.keyframes;
  summary.described -= f.is_described();
  summary.blended -= f.is_blended();
  ++summary.rejected;
  // Its rejections, and its frame's, go with the next patch written (or the last one's late list).
  rejected.push_back({f.index, f.source, "isolated"});
  std::sort(rejected.begin(), rejected.end(), [](const RejectedFrame& a, const RejectedFrame& b) { return a.index < b.index; });
  for (auto& w : pending) w.thin_overlap.reset();
  ForgetPatch();
  last = Placed{};
  next_patch_id = patch_id--;  // the next patch takes its number; patch_id: the last one written
}

void Mosaicker::Impl::ListLateRejections() {
  summary.rejected_frames.insert(summary.rejected_frames.end(), rejected.begin(), rejected.end());
  std::sort(summary.rejected_frames.begin(), summary.rejected_frames.end(),
            [](const RejectedFrame& a, const RejectedFrame& b) { return a.index < b.index; });
  if (rejected.empty() || summary.patches == 0) return;
  PatchSidecar s = store.ReadSidecar(patch_id);
  s.rejected.insert(s.rejected.end(), rejected.begin(), rejected.end());
  store.UpdateSidecar(s);
  rejected.clear();
}

// A frame that cannot be registered: kept for a second chance against the frames after it and
// to start the next patch from; the patch closes only after several in a row failed.
FrameReport Mosaicker::Impl::Lost(const std::shared_ptr<PreparedFrame>& p, FrameReport r, const std::string& reason) {
  FrameReport rep = Reject(r, reason);
  if (gate) gate->Skip();
  // Featureless by SIFT too: dark ground may still be followed (BreakAt, SecondChance).
  if (canvas && options.recover) {
    pending.push_back({p, rep, 0, std::nullopt});
    if (pending.size() > 6) pending.pop_front();
  }
  if (++lost >= options.max_lost_frames && canvas) {
    // The thread is lost: the waiting frames may start the next patch (BreakAt), not this one.
    ClosePatch("lost_tracking");
    lost = 0;
  }
  return rep;
}

// Tracking broke (the next lane does not overlap this one, a turn too sharp): when the frame
// registers to a frame rejected just before it, the patch closes and a new one starts from that
// frame, so no frame is lost at a break. True when it did.
bool Mosaicker::Impl::BreakAt(const std::shared_ptr<PreparedFrame>& p) {
  if (pending.empty() || !options.recover) return false;
  constexpr int kBreakTries = 2;
  for (auto it = pending.rbegin(); it != pending.rend(); ++it) {
    if (it->frame->size != frame_size || it->break_tries >= kBreakTries) continue;
    // Following too: dark ground at a lane's start can leave SIFT too few matches where
    // following holds (small-narrow-lights: 16 matches, none kept, between a lane's first two).
    const EgomotionResult ego = RegisterPair(*p, *it->frame);
    if (!ego.ok || !AssessSupport(ego, frame_size, support_options).strong) {
      ++it->break_tries;
      continue;
    }
    // This one opens the next patch; the others wait on: the frames before it may be the lane's
    // first too, and are tried against it at once.
    Pending start = *it;
    pending.erase(std::next(it).base());
    FrameReport r = Unreject(start.report);
    if (canvas) ClosePatch("lost_tracking");
    StartPatch(start.frame, r, std::nullopt);
    frames.back().registered_by = "second_chance";
    Laps lap{this, {}};
    SecondChance(start.frame, keys.back().to_patch, lap);
    return true;
  }
  return false;
}

}  // namespace rolamos
