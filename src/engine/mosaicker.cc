#include "rolamos/mosaicker.hpp"

#include "engine/mosaicker_impl.h"

namespace rolamos {

namespace {

std::string SizeText(cv::Size s) { return std::to_string(s.width) + "x" + std::to_string(s.height); }

}  // namespace

bool MosaickerOptions::IsValid(std::string* error) const {
  if (!ToFeatureOptions(*this).IsValid(error) || !ToEgomotionOptions(*this).IsValid(error) ||
      !ToPreprocessOptions(*this).IsValid(error) || !ToEccOptions(*this).IsValid(error) ||
      !ToTrackerOptions(*this).IsValid(error) || !ToPatchAdjustmentOptions(*this).IsValid(error))
    return false;
  if (track_halve != "auto" && track_halve != "always" && track_halve != "never") {
    *error = "tracking halving \"" + track_halve + "\" is none of auto, always, never";
    return false;
  }
  if (!(keyframe_overlap > 0.1 && keyframe_overlap <= 1.0) ||
      !(keyframe_min_overlap > 0.05 && keyframe_min_overlap <= keyframe_overlap)) {
    *error = "keyframe overlap " + std::to_string(keyframe_overlap) + " must be in (0.1, 1] and the minimum " +
             std::to_string(keyframe_min_overlap) + " in (0.05, keyframe overlap]";
    return false;
  }
  if (!FollowedFeatureOptions(ToFeatureOptions(*this), *this).IsValid(error)) {
    *error = "features of followed keyframes (" + std::to_string(followed_max_features) + "): " + *error;
    return false;
  }
  if (!(blend_overlap > 0 && blend_overlap <= 1.0)) {
    *error = "blend overlap " + std::to_string(blend_overlap) + " must be in (0, 1]";
    return false;
  }
  if (!(describe_overlap > 0 && describe_overlap <= 1.0)) {
    *error = "describe overlap " + std::to_string(describe_overlap) + " must be in (0, 1]";
    return false;
  }
  if (!(still_describe_overlap > 0 && still_describe_overlap <= 1.0) ||
      !(still_blend_overlap > 0 && still_blend_overlap <= 1.0)) {
    *error = "describe and blend overlaps of stills " + std::to_string(still_describe_overlap) + ", " +
             std::to_string(still_blend_overlap) + " must be in (0, 1]";
    return false;
  }
  if (still_track_points < 0 || still_track_points > 5000) {
    *error = "points a still hands on " + std::to_string(still_track_points) + " must be in [0, 5000]";
    return false;
  }
  if (!(feather_sigma >= 0 && feather_sigma <= 10)) {
    *error = "feather sigma must be in [0, 10] (0 = plain averaging)";
    return false;
  }
  if (!(patch_megapixels >= 0.1 && patch_megapixels <= 2000)) {
    *error = "patch budget " + std::to_string(patch_megapixels) + " megapixels is outside 0.1..2000";
    return false;
  }
  if (mask != "" && mask != "auto" && !std::filesystem::exists(mask)) {
    *error = "static overlay mask \"" + mask + "\" does not exist";
    return false;
  }
  if (!(patch_frames_mb >= 16)) {
    *error = "the memory for a patch's frames must be at least 16 MB, not " + std::to_string(patch_frames_mb);
    return false;
  }
  if (patch_memory_mb < 0) {
    *error = "patch memory budget cannot be negative";
    return false;
  }
  if (checkpoint_frames < 0 || checkpoint_frames == 1) {
    *error = "checkpoint every " + std::to_string(checkpoint_frames) + " frames: 0 (none) or at least 2";
    return false;
  }
  if (max_lost_frames < 1) {
    *error = "max lost frames must be at least 1";
    return false;
  }
  PixelLayout rgba;
  rgba.width = rgba.height = 1024;
  rgba.channels = 4;
  return tiff.IsValid(rgba, error);
}

long long MosaickerOptions::PixelBudget(cv::Size frame) const {
  long long budget = static_cast<long long>(patch_megapixels * 1e6);
  budget = std::max(budget, 2LL * frame.width * frame.height);
  if (patch_memory_mb > 0)  // the canvas holds 16 bytes a pixel (3 float sums and a weight)
    budget = std::min(budget, static_cast<long long>(patch_memory_mb * 1024 * 1024 / 16));
  return budget;
}


void Mosaicker::Impl::InitCamera(cv::Size size) {
  frame_size = size;
  K = pre.CameraMatrix(size);
  summary.track_scale = tracker.options().ScaleFor(size);
  track_points = tracker.options().PointsFor(size);
  MakeWeights();
  MotionGateOptions g;
  g.enabled = options.kalman;
  gate = std::make_unique<MotionGate>(g, size);
}

const FeatureExtractor& Mosaicker::Impl::ExtractorFor(const PreparedFrame& p) const {
  if (p.coarse_features) return p.followed_features ? coarse_followed_extractor : coarse_extractor;
  return p.followed_features ? followed_extractor : extractor;
}

Features Mosaicker::Impl::Describe(const cv::Mat& image, const FeatureExtractor& ex, long* mask_seen) {
  const double scale = ex.options().ScaleFor(image.size());
  cv::Mat specks;
  const cv::Mat detect = pre.DetectionImage(image, scale, &specks);
  cv::Mat mask = specks;
  {
    std::lock_guard<std::mutex> lock(mask_mutex);
    if (!usable_small.empty() && usable_small.size() == detect.size())
      mask = mask.empty() ? usable_small : (mask & usable_small);
    if (mask_seen) *mask_seen = mask_generation;
  }
  return ex.ExtractScaled(detect, scale, mask);
}

std::shared_ptr<const Features> Mosaicker::Impl::FeaturesOf(PreparedFrame& p) {
  std::call_once(p.features_once, [&] {
    if (p.ahead && p.ahead_by == &ExtractorFor(p)) {
      std::lock_guard<std::mutex> lock(mask_mutex);
      if (p.ahead_mask == mask_generation) p.features = p.ahead;
    }
    if (p.features) {
      ++features_ahead_used;
    } else {
      Laps lap{this, {}};
      p.features = std::make_shared<const Features>(Describe(p.image, ExtractorFor(p)));
      lap(kFeatures);
    }
    p.ahead.reset();
  });
  return p.features;
}

FrameReport Mosaicker::Impl::Reject(FrameReport r, const std::string& reason) {
  r.status = "rejected";
  r.reason = reason;
  r.patch_id = canvas ? patch_id : 0;
  rejected.push_back({r.index, r.source, reason});
  ++summary.rejected;
  last_rejected = r.index;
  return r;
}

FrameReport Mosaicker::Impl::Unreject(const FrameReport& report) {
  rejected.erase(std::remove_if(rejected.begin(), rejected.end(),
                                [&](const RejectedFrame& x) { return x.index == report.index; }),
                 rejected.end());
  --summary.rejected;
  ++summary.recovered;
  if (last_rejected == report.index) last_rejected = -1;
  FrameReport r = report;
  r.status = "stitched";
  r.reason.clear();
  return r;
}

FrameRecord Mosaicker::Impl::RecordOf(const FrameReport& r, const cv::Matx33d& to_patch) const {
  FrameRecord rec;
  rec.index = r.index;
  rec.source = r.source;
  rec.frame_to_patch = ToArray9(to_patch);
  rec.matches = r.matches;
  rec.inliers = r.inliers;
  rec.ecc = r.ecc;
  rec.status = "stitched";
  return rec;
}

// The frame placed: a keyframe (fitted against the recent keyframes, refined by ECC, blended)
// or a frame followed between keyframes (placed only).
FrameReport Mosaicker::Impl::Place(const std::shared_ptr<PreparedFrame>& p, Candidate best, FrameReport r, Laps& lap) {
  const bool doubtful = !best.support.strong;
  r.matches = best.ego.matches;
  r.inliers = best.ego.inliers;
  r.bilateral_error = best.ego.bilateral_error_mean;
  r.status = "stitched";
  r.patch_id = patch_id;
  r.continues = true;
  lost = 0;
  auto fill = [&](FrameRecord& rec) {
    if (best.ego.motion && best.tracked()) {
      Egomotion e;
      for (int i = 0; i < 9; ++i) e.R[static_cast<size_t>(i)] = best.ego.motion->R.val[i];
      for (int i = 0; i < 3; ++i) {
        e.t[static_cast<size_t>(i)] = best.ego.motion->t[i];
        e.n[static_cast<size_t>(i)] = best.ego.motion->n[i];
      }
      rec.egomotion = e;
    }
    rec.bilateral_error = best.ego.bilateral_error_mean;
    if (!best.tracked()) rec.registered_by = best.registered_by;
    if (doubtful) rec.doubtful = true;
  };
  // The same view again (a vehicle holding still, a repeated frame): placed, nothing to blend.
  const bool duplicate = best.support.strong && MaxCornerShift(best.to_patch, last.to_patch, frame_size) < 0.25;
  if (duplicate) r.note = "duplicate of frame " + std::to_string(last.index);
  if (duplicate || !WantsKeyframe(best, best.to_patch)) {
    gate->Accept(MotionFromLast(best.to_patch));
    FrameRecord rec = RecordOf(r, best.to_patch);
    fill(rec);
    AddFollowed(p, best.to_patch, std::move(rec), best.Links(r.index));
    if (!pending.empty()) SecondChance(p, best.to_patch, lap);
    return r;
  }
  r.keyframe = true;
  std::vector<FrameLink> found;
  int fitted = 1;
  cv::Matx33d to_patch = FitToKeyframes(*p, best, &found, &fitted);
  for (auto& l : found) l.a = r.index;
  lap(kKeyframeFit);
  const size_t frame_bytes = KeyframeBytes(*p);
  const bool memory_full = keyframe_bytes + frame_bytes > static_cast<size_t>(options.patch_frames_mb * 1024 * 1024);
  const bool checkpoint = options.checkpoint_frames > 0 && static_cast<int>(frames.size()) >= options.checkpoint_frames;
  if (memory_full || checkpoint || !canvas->Fits(PatchCanvas::FrameBounds(to_patch, frame_size))) {
    // The pixel budget is reached: close the patch, start the next one with this frame, and
    // remember how the two join (this frame, adjusted with both).
    OpenJoinedPatch(p, r, to_patch, std::move(found),
                    memory_full ? "frame_memory" : checkpoint ? "checkpoint" : "pixel_budget");
    return r;
  }
  // ECC aligns a keyframe with the patch image it is blended into; the others are placed by the
  // adjustment.
  bool blend = Blends(best, to_patch);
  if (LastStillUncovered(blend ? &to_patch : nullptr)) {
    BlendLastKeyframe();
    blend = Blends(best, to_patch);
  }
  if (options.ecc && blend) {
    cv::Mat gray;
    BgrToGrey(p->image, gray);
    const cv::Mat u = Usable();
    const EccResult ecc = RefineWithEcc(gray, to_patch, *canvas, ecc_options,
                                        u.size() == frame_size ? u : cv::Mat());
    r.ecc = ecc.correlation;
    if (ecc.applied) {
      r.ecc_shift = MaxCornerShift(to_patch, ecc.frame_to_patch, frame_size);
      to_patch = ecc.frame_to_patch;
    }
  }
  lap(kEcc);
  gate->Accept(MotionFromLast(to_patch));
  FrameRecord rec = RecordOf(r, to_patch);
  fill(rec);
  rec.ecc_shift_px = r.ecc_shift;
  if (options.patch_fit) rec.patch_frames = fitted;
  if (found.empty()) found = best.Links(r.index);
  AddKeyframe(p, to_patch, best.tracked() ? &best : nullptr, std::move(found), std::move(rec), true, blend);
  if (!pending.empty()) SecondChance(p, to_patch, lap);
  return r;
}

// One frame of another size is rejected; two in a row mean the camera changed: the patch closes
// and the frames go on at the new size, the first of them no longer rejected.
std::optional<FrameReport> Mosaicker::Impl::FollowSizeChange(const std::shared_ptr<PreparedFrame>& p, FrameReport& r) {
  if (!resized || resized->size != p->size) {
    resized = p;
    resized_report = Reject(r, "size_changed: " + SizeText(p->size) + ", the survey is " + SizeText(frame_size));
    return resized_report;
  }
  FrameReport first = Unreject(resized_report);
  DropWaiting();  // frames of the old size join none of the new
  ClosePatch("size_changed");
  InitCamera(p->size);
  if (FeaturesOf(*resized)->strong >= options.min_inliers) StartPatch(resized, first, std::nullopt);
  else Reject(first, "featureless");
  resized.reset();
  if (canvas) return std::nullopt;  // this frame follows the first of its size
  if (FeaturesOf(*p)->strong < options.min_inliers) return Lost(p, r, "featureless");
  StartPatch(p, r, std::nullopt);
  return r;
}

// No patch is open: the frame opens one, unless a frame rejected before it (the thread was
// lost) registers to it and opens it instead, this frame then placed in it.
FrameReport Mosaicker::Impl::OpenPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport r, Laps& lap) {
  if (FeaturesOf(*p)->strong < options.min_inliers) return Lost(p, r, "featureless");
  if (BreakAt(p)) {
    gate->Predict(StepsSinceLast(*p, r.index));
    Candidate again = Track(p, Start::kCorrelated);
    if (Usable(again)) return Place(p, std::move(again), r, lap);
    // The frames still waiting may overlap this one, the next patch's first, more.
    ClosePatch("lost_tracking");
    StartPatch(p, r, std::nullopt);
    SecondChance(p, cv::Matx33d::eye(), lap);
    return r;
  }
  StartPatch(p, r, std::nullopt);
  return r;
}

Mosaicker::Mosaicker(Store store, const MosaickerOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("mosaic options", error);
  // "auto" needs the first frames before the first is prepared: MosaicInput finds the mask and
  // gives the engine its file. Pushed frames have nobody to look ahead: no mask, and said so.
  MosaickerOptions o = options;
  std::string mask_note;
  if (o.mask == "auto") {
    o.mask.clear();
    mask_note = "mask auto: frames pushed one by one are not looked ahead at; no overlay mask (MosaicInput finds one)";
  }
  impl_ = std::make_unique<Impl>(store, o);
  impl_->mask_path = o.mask;
  impl_->summary.mask_note = mask_note;
  impl_->next_patch_id = store.NextPatchId();
}

Mosaicker::~Mosaicker() = default;

void Mosaicker::OnPatch(std::function<void(const PatchSidecar&)> callback) {
  impl_->writer.OnPatch(std::move(callback));
}

std::shared_ptr<PreparedFrame> Mosaicker::Prepare(const cv::Mat& input, const std::string& source,
                                                  const std::string& error) {
  Impl& m = *impl_;
  auto p = std::make_shared<PreparedFrame>();
  p->source = source;
  p->error = input.empty() ? (error.empty() ? "unreadable" : error) : "";
  if (input.empty()) return p;
  Impl::Laps lap{&m, {}};
  cv::Mat frame = input;
  if (frame.depth() != CV_8U) frame.convertTo(frame, CV_8U, frame.depth() == CV_16U ? 1.0 / 257.0 : 255.0);
  if (frame.channels() == 1) cv::cvtColor(frame, frame, cv::COLOR_GRAY2BGR);
  if (frame.channels() == 4) cv::cvtColor(frame, frame, cv::COLOR_BGRA2BGR);
  p->size = frame.size();
  try {
    p->image = m.pre.Undistort(frame);
  } catch (const Error& e) {
    // A frame the calibration does not fit: rejected with the reason, the run goes on.
    p->error = e.what();
    p->image.release();
    return p;
  }
  cv::Mat usable;
  if (std::lock_guard<std::mutex> lock(m.mask_mutex); !m.mask_path.empty()) {
    if (m.usable.empty() || m.usable.size() != p->size) {
      m.usable = 255 - ReadStaticMask(m.mask_path, p->size);
      const double scale = m.extractor.options().ScaleFor(p->size);
      cv::resize(m.usable, m.usable_small, cv::Size(), scale, scale, cv::INTER_NEAREST);
      // Features need a margin around an overlay: their descriptors reach out.
      cv::erode(m.usable_small, m.usable_small, cv::Mat(), cv::Point(-1, -1), 4);
      ++m.mask_generation;
    }
    usable = m.usable;
  }
  p->track = m.tracker.Prepare(p->image, usable);
  lap(Impl::kPreprocess);
  if (m.features_ahead) {
    p->ahead_by = &m.extractor;
    p->ahead = std::make_shared<const Features>(m.Describe(p->image, *p->ahead_by, &p->ahead_mask));
    lap(Impl::kFeatures);
  }
  return p;
}

FrameReport Mosaicker::Push(const cv::Mat& frame, const std::string& source, const std::string& error) {
  return Integrate(Prepare(frame, source, error));
}

FrameReport Mosaicker::Integrate(const std::shared_ptr<PreparedFrame>& p) {
  Impl& m = *impl_;
  const auto t0 = std::chrono::steady_clock::now();
  Impl::Laps lap{&m, {}};
  FrameReport r;
  r.index = m.summary.frames++;
  r.source = p->source;
  p->camera_frame = m.camera_frames += 1 + std::max(0, p->skipped_before);
  auto done = [&](FrameReport rep) {
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (p) m.NoteFeaturesNeeded(*p);
    return rep;
  };
  if (!p->error.empty()) return done(m.Reject(r, p->error));
  if (m.frame_size.area() == 0) m.InitCamera(p->size);
  if (p->size != m.frame_size)
    if (auto rep = m.FollowSizeChange(p, r)) return done(*rep);
  m.resized.reset();
  if (m.mask_changed && !m.Usable().empty()) {  // a mask given mid-run (UseMask), read by a preparer
    m.mask_changed = false;
    m.MakeWeights();
  }
  if (!m.canvas) return done(m.OpenPatch(p, r, lap));
  m.gate->Predict(m.StepsSinceLast(*p, r.index));
  // 1. Followed from the current keyframe, from where the motion model expects it; again from a
  //    coarse correlation when that failed. (Correlating first everywhere saves a second follow
  //    on half the frames of a jittered survey, but places frames slightly worse: 0.40 -> 0.45 px
  //    on lawn-984, 0.32 -> 0.37 on lanes-apart. So only where predictions have lately failed and
  //    the frame correlates confidently far from the prediction, from where a follow almost
  //    never holds, is the predicted start tried last instead: PredictionFarOff.)
  //    Then from where the last frame was: in turns that change from frame to frame (a random
  //    walk) the model overshoots by a turn Lucas-Kanade's square windows cannot follow, and
  //    recovery by SIFT made one frame in six a keyframe (video-1292-random: 50 of 300 frames
  //    recovered; 12 now, bench/RESULTS.md, session 18). Without a prediction the tries would
  //    be the same one.
  //    Each start's follow gives up after a sample that failed. When recovery finds nothing
  //    strong, those are followed whole after all: a weak follow the motion model agrees with
  //    places a frame on faint ground (MosaickerRobustness.RealLowContrastStills...).
  using Start = Impl::Start;
  std::vector<Impl::Tried> tried;
  bool far = m.PredictionFarOff(*p);
  Impl::Candidate best = m.FollowStarts(p, far, &tried, true);
  //    When the keyframe does not hold the frame and frames were followed since, the last of
  //    them becomes a keyframe and the frame is followed from it: it overlaps the frame more.
  //    Stills that overlap little were otherwise followed across the last keyframe's thinner
  //    strip, weakly or not at all (a real low-contrast still at a fifth of its keyframe: 17
  //    inliers from it with a 21-pixel window, lost with 31; 72 from the frame between).
  if (!m.Settled(best) && m.LastCanBeKeyframe()) {
    m.PromoteLast();
    tried.clear();
    far = m.PredictionFarOff(*p);
    best = m.FollowStarts(p, far, &tried, true);
  }
  const bool gave_up = std::any_of(tried.begin(), tried.end(), [](const Impl::Tried& t) { return t.cut_short; });
  const auto from_prediction = std::find_if(tried.begin(), tried.end(),
                                            [](const Impl::Tried& t) { return t.start == Start::kPredicted; });
  const bool predicted_held = !far && from_prediction != tried.end() && from_prediction->result.support.strong &&
                              m.Usable(from_prediction->result);
  m.since_prediction_failed = predicted_held ? std::min(m.since_prediction_failed + 1, 1 << 20) : 0;
  lap.Restart();  // Track timed itself
  // 2. The motion model arbitrates between what following and recovery found.
  if (!m.Settled(best)) {
    m.wanted_now = m.needed_here_now = true;
    const auto f = m.FeaturesOf(*p);
    if (f->strong < m.options.min_inliers) return done(m.Lost(p, r, "featureless"));
    std::optional<Matches> with_last_key;
    std::vector<Impl::Candidate> more;
    if (m.options.recover) more = m.Recover(p, lap, &with_last_key);
    if (gave_up && std::none_of(more.begin(), more.end(), [](const Impl::Candidate& c) { return c.support.strong; })) {
      best = m.FollowStarts(p, far, &tried, false);
      lap.Restart();  // Track timed itself
    }
    if (m.options.recover) {
      if (best.ego.ok) more.push_back(best);
      if (const Impl::Candidate* pick = m.Pick(more)) best = *pick;
      // 3. Frames that overlap little (stills from an AUV, a lane joined without a turn): of a
      //    frame's max_features, the strip it shares with the last keyframe may hold too few for
      //    enough inliers. When nothing else placed the frame, and its features were capped
      //    (there are more to find), it and the last keyframe are described three times as
      //    densely. A strip is a weak hold for a whole patch (it bent lanes joined so by up to
      //    3 px): the frame opens the next patch, joined to this one by that registration.
      if (!m.Usable(best))
        if (auto rep = m.RecoverAcrossThinOverlap(p, *f, best, r, with_last_key ? &*with_last_key : nullptr, lap))
          return done(*rep);
    }
  }
  if (!m.Usable(best)) {
    const std::string reason = best.ego.ok ? (best.verdict.consistent ? best.support.weakness : "kalman_gate")
                                           : best.ego.failure;
    // The next lane, or the ground after a gap: it may join the frames rejected just before.
    if (m.BreakAt(p)) {
      m.gate->Predict(m.StepsSinceLast(*p, r.index));
      Impl::Candidate again = m.Track(p, Start::kCorrelated);
      if (m.Usable(again)) return done(m.Place(p, std::move(again), r, lap));
    }
    return done(m.Lost(p, r, reason));
  }
  return done(m.Place(p, std::move(best), r, lap));
}

LivePreview Mosaicker::Preview(double scale, double max_megapixels, bool image) const {
  const Impl& m = *impl_;
  LivePreview out;
  if (!m.canvas || m.canvas->empty() || m.frames.empty()) return out;
  if (image) {
    const cv::Rect& data = m.canvas->data();
    const double area = std::max(1.0, double(data.width) * data.height);
    scale = std::min({scale, m.canvas->scale(), std::sqrt(max_megapixels * 1e6 / area)});
    cv::Point2d origin;
    if (!m.canvas->RenderColour(scale, &out.image, &origin)) return out;
    // Image pixel q = (p - origin + 0.5) s - 0.5.
    const double s = scale;
    out.patch_to_image = cv::Matx33d(s, 0, (0.5 - origin.x) * s - 0.5, 0, s, (0.5 - origin.y) * s - 0.5, 0, 0, 1);
  }
  out.patch_id = m.patch_id;
  out.frames = static_cast<int>(m.frames.size());
  out.last_index = m.frames.back().index;
  out.last_source = m.frames.back().source;
  const double w = m.frame_size.width, h = m.frame_size.height;
  out.frame_size = m.frame_size;
  for (const FrameRecord& f : m.frames) {
    out.track.push_back(ApplyHomography(ToMatx(f.frame_to_patch), {w / 2, h / 2}));
    out.track_frames.push_back(f.source);
  }
  for (const cv::Point2d c : {cv::Point2d(0, 0), cv::Point2d(w, 0), cv::Point2d(w, h), cv::Point2d(0, h)})
    out.footprint.push_back(ApplyHomography(m.last.to_patch, c));
  if (m.link) {
    out.previous_patch = m.link->previous_patch;
    out.to_previous_first = m.link_to_first;
  }
  return out;
}

void Mosaicker::UseMask(const std::string& path) {
  Impl& m = *impl_;
  ReadStaticMask(path, cv::Size(16, 16));  // fails here, naming the file, not in a preparer
  std::lock_guard<std::mutex> lock(m.mask_mutex);
  m.mask_path = path;
  m.usable.release();  // read again, at the frames' size, by the next frame prepared
  m.usable_small.release();
  ++m.mask_generation;
  m.mask_changed = true;
}

void Mosaicker::ShedLoad(bool on, double describe_overlap) {
  if (!(describe_overlap > 0 && describe_overlap <= 1.0))
    Fail("describe overlap while shedding load", std::to_string(describe_overlap) + " must be in (0, 1]");
  // Read only on this (the integrating) thread, by Describes.
  impl_->shedding = on;
  impl_->shed_describe_overlap = describe_overlap;
}

double Mosaicker::LastStepFraction() const {
  const Impl& m = *impl_;
  if (m.frames.size() < 2) return 0;
  const double w = m.frame_size.width, h = m.frame_size.height;
  const cv::Point2d a = ApplyHomography(ToMatx(m.frames[m.frames.size() - 2].frame_to_patch), {w / 2, h / 2});
  const cv::Point2d b = ApplyHomography(ToMatx(m.frames.back().frame_to_patch), {w / 2, h / 2});
  const cv::Point2d d = b - a;
  const double length = std::hypot(d.x, d.y);
  if (length < 1e-9) return 0;
  // The frame's extent along the motion (an axis-aligned frame in its own grid, roughly).
  const double extent = w * std::abs(d.x) / length + h * std::abs(d.y) / length;
  return length / extent;
}

double MosaicSummary::RestCpuSeconds() const {
  double named = 0;
  for (const auto& stage : stage_seconds) named += stage.second;
  return std::max(0.0, cpu_seconds - named);
}

MosaicSummary Mosaicker::Finish() {
  Impl& m = *impl_;
  m.DropWaiting();
  m.ClosePatch("end");
  m.keyframe_pool.Wait();
  m.writer.Wait();
  m.summary.adjusted = m.writer.adjusted();
  for (const auto& u : m.writer.unadjusted()) {
    m.summary.unadjusted_why.emplace_back(u.patch, u.why);
    if (u.miss == PatchAdjustment::Miss::kMisfit) m.summary.misfit_patches.push_back(u.patch);
    if (u.miss == PatchAdjustment::Miss::kTooFewFrames) m.summary.trivial_patches.push_back(u.patch);
  }
  m.summary.unadjusted = static_cast<int>(m.summary.unadjusted_why.size());
  m.ListLateRejections();
  if ((m.options.flat_field || m.options.water_colour) && m.colour->frames() > 0)
    WriteFileAtomic(m.store.dir() + "/lighting.json", m.colour->ToJson());
  m.writer_lock.reset();  // every patch written: another engine may go on with the store
  m.summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - m.start).count();
  m.summary.cpu_seconds = ProcessCpuSeconds() - m.cpu_start;
  m.summary.peak_rss_mb = PeakRssMb();
  m.summary.features_ahead = m.features_ahead_used;
  static const char* names[] = {"preprocess", "tracking", "egomotion", "features", "recovery",
                                "keyframe fit", "ecc", "working canvas", "keyframe filter", "loop links"};
  m.summary.stage_seconds.clear();
  for (int i = 0; i < Impl::kStages; ++i)
    m.summary.stage_seconds.emplace_back(names[i], 1e-9 * static_cast<double>(m.stage_ns[i].load()));
  // The writer's thread: adjustment, full-resolution blending and encoding of patches.
  m.summary.stage_seconds.emplace_back("adjustment", m.writer.adjust_seconds());
  m.summary.stage_seconds.emplace_back("patch writing", m.writer.busy_seconds() - m.writer.adjust_seconds());
  // The patch image's tiles, compressed on the encoders' threads (not the writer's own).
  m.summary.stage_seconds.emplace_back("tile encoding", m.writer.encode_seconds());
  m.summary.keyframe_stages = {"features", "keyframe fit", "ecc", "working canvas", "keyframe filter",
                               "loop links", "adjustment", "patch writing", "tile encoding"};
  return m.summary;
}

}  // namespace rolamos
