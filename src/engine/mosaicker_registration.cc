// Mosaicker's registration of a frame: followed from the keyframe (several starts), recovered by
// SIFT against the patch, across a thin overlap, or given a second chance by the frames after it.
#include "engine/mosaicker_impl.h"

namespace rolamos {

Mosaicker::Impl::Candidate Mosaicker::Impl::Assess(EgomotionResult ego, const cv::Matx33d& target_to_patch,
                                                   const std::string& by, int target) {
  Candidate c;
  c.ego = std::move(ego);
  c.target = target;
  c.registered_by = by;
  c.support = AssessSupport(c.ego, frame_size, support_options);
  if (c.ego.ok) {
    c.to_patch = target_to_patch * c.ego.H;
    c.verdict = gate->Evaluate(MotionFromLast(c.to_patch));
  }
  return c;
}

// The frame followed from the current keyframe, starting where the motion model puts it, or
// where one phase correlation of the coarsest levels moves that (kCorrelated) or the last frame's
// place (kUnmoved). Without a prediction all three start from the correlation.
Mosaicker::Impl::Candidate Mosaicker::Impl::Track(const std::shared_ptr<PreparedFrame>& p, Start start,
                                                  std::vector<Tried>* tried, bool may_give_up) {
  Laps lap{this, {}};
  const Key& key = keys.back();
  const bool predicted = start != Start::kUnmoved && start != Start::kTurned && gate->Predicted();
  cv::Matx33d guess = StartGuess(start);
  if (start == Start::kTurned) {
    double response = 0;
    guess = tracker.CoarseTurn(*key.frame->track, *p->track, guess, &response);
    if (!(response > 0.05)) return Candidate{};  // no turn correlates: nothing to follow from
  } else if (start != Start::kPredicted || !predicted) {
    const Correlated& c = Correlate(*p, guess);
    if (c.response > 0.05 || !predicted) guess = c.shifted;
  }
  // A correlation too weak to move the prediction leaves the guess the predicted follow had.
  Tried* again = nullptr;
  if (tried)
    for (Tried& t : *tried)
      if (t.guess == guess) {
        if (!t.cut_short || may_give_up) return t.result;
        again = &t;
      }
  const TrackFlow flow =
      tracker.Follow(*key.frame->track, *p->track, key.points, guess, key.windows.get(), may_give_up);
  std::vector<cv::Point2f> from, to;
  std::vector<size_t> kept;
  flow.Kept(key.points, &from, &to, &kept);
  std::vector<long long> ids;
  for (size_t i : kept) ids.push_back(key.ids[i]);
  lap(kTracking);
  Candidate c = Assess(EstimateEgomotion(from, to, K, ego_options), key.to_patch, "", key.index);
  for (int i : c.ego.inlier_index) {
    c.ids.push_back(ids[size_t(i)]);
    c.at.push_back(from[size_t(i)]);
  }
  lap(kEgomotion);
  if (again) *again = {again->start, guess, c, flow.cut_short};
  else if (tried) tried->push_back({start, guess, c, flow.cut_short});
  return c;
}

Mosaicker::Impl::Candidate Mosaicker::Impl::FollowStarts(const std::shared_ptr<PreparedFrame>& p, bool far,
                                                         std::vector<Tried>* tried, bool may_give_up) {
  const bool predicted = gate->Predicted().has_value();
  Candidate best = far ? Candidate{} : Track(p, Start::kPredicted, tried, may_give_up);
  auto held = [&] { return Usable(best) && best.support.strong; };
  for (Start start : {Start::kCorrelated, Start::kUnmoved, Start::kPredicted}) {
    if (!predicted || held()) break;
    if (start == Start::kPredicted && !far) break;
    Candidate again = Track(p, start, tried, may_give_up);
    if (Usable(again) && (!Usable(best) || again.support.strong)) best = std::move(again);
  }
  //    Last, when asked (MosaickerOptions::track_turn_search_deg), turned by what correlates
  //    best, before SIFT is: a random walk's stills turn by up to 40 degrees, which no start
  //    above foresees (random: 133 of 300 stills recovered by SIFT, 56 with it; bench/RESULTS.md,
  //    session 33).
  if (options.track_turn_search_deg > 0 && !Settled(best)) {
    Candidate again = Track(p, Start::kTurned, tried, may_give_up);
    if (Settled(again)) best = std::move(again);
  }
  return best;
}

cv::Matx33d Mosaicker::Impl::StartGuess(Start start) const {
  // Where the frame is expected: the last placed frame moved by the predicted motion.
  const bool from_last = start == Start::kUnmoved || start == Start::kTurned;
  const std::optional<FrameMotion> predicted = from_last ? std::nullopt : gate->Predicted();
  cv::Matx33d frame_to_key = keys.back().to_patch.inv() * last.to_patch;
  if (predicted) frame_to_key = frame_to_key * HomographyOf(*predicted, frame_size);
  return frame_to_key.inv();  // key -> frame
}

const Mosaicker::Impl::Correlated& Mosaicker::Impl::Correlate(const PreparedFrame& p, const cv::Matx33d& guess) {
  const Key& key = keys.back();
  if (correlated.frame != summary.frames || correlated.key != key.index || correlated.guess != guess) {
    correlated.frame = summary.frames;
    correlated.key = key.index;
    correlated.guess = guess;
    correlated.shifted = tracker.CoarseShift(*key.frame->track, *p.track, guess, &correlated.response);
  }
  return correlated;
}

// A follow from a start this far (tracking pixels) from where the frame correlates confidently
// held on 5 of ~930 frames of the 28 kinds of bench/run_engine_spread.py that were so; nearer,
// many hold (30-40: a third). Those far ones were each followed twice, the first time in vain:
// half the frames of jittered stills (bench/RESULTS.md, session 40).
constexpr double kFarShiftPx = 40;

constexpr double kFarResponse = 0.3;

bool Mosaicker::Impl::PredictionFarOff(const PreparedFrame& p) {
  if (since_prediction_failed >= 8 || !gate->Predicted()) return false;
  const cv::Matx33d guess = StartGuess(Start::kPredicted);
  const Correlated& c = Correlate(p, guess);
  const cv::Point2d centre(frame_size.width / 2.0, frame_size.height / 2.0);
  const double shift = p.track->scale * cv::norm(ApplyHomography(c.shifted, centre) - ApplyHomography(guess, centre));
  return c.response >= kFarResponse && shift >= kFarShiftPx;
}

// The frame against the patch's keyframes (features: rotation and scale do not matter) and the
// patch image around the last frame, when following it failed.
std::vector<Mosaicker::Impl::Candidate> Mosaicker::Impl::Recover(const std::shared_ptr<PreparedFrame>& p, Laps& lap,
                                                                 std::optional<Matches>* with_last_key) {
  std::vector<Candidate> found;
  const auto f = FeaturesOf(*p);
  lap.Restart();  // FeaturesOf timed itself (counting it here too counted the features twice)
  // 1. The patch's recent keyframes that overlap the last frame, newest first.
  int tried = 0;
  for (auto it = keys.rbegin(); it != keys.rend() && tried < 4; ++it) {
    if (!it->described || FootprintOverlap(last.to_patch, it->to_patch, frame_size) < 0.1) continue;
    ++tried;
    const auto& theirs = it->products.get().features;
    if (!theirs) continue;
    const Matches m = MatchFeatures(*f, *theirs, extractor.options());
    if (with_last_key && it == keys.rbegin()) *with_last_key = m;
    Candidate c = Assess(EstimateEgomotion(m.from, m.to, K, ego_options), it->to_patch, "keyframe", it->index);
    if (c.ego.ok) found.push_back(std::move(c));
    if (!found.empty() && found.back().support.strong && found.back().verdict.consistent) break;
  }
  lap(kRecovery);
  for (const auto& c : found)
    if (c.support.strong) return found;
  // 2. The patch image around the last frame, a frame's size each way: the frame may have turned
  //    any way and need not overlap the last keyframe.
  const cv::Rect2d around = PatchCanvas::FrameBounds(last.to_patch, frame_size);
  const double grow = std::max(frame_size.width, frame_size.height);
  const cv::Rect wanted(static_cast<int>(std::floor(around.x - grow)), static_cast<int>(std::floor(around.y - grow)),
                        static_cast<int>(std::ceil(around.width + 2 * grow)), static_cast<int>(std::ceil(around.height + 2 * grow)));
  const double scale = extractor.options().ScaleFor(frame_size);
  cv::Mat gray, mask;
  cv::Point2d origin;
  if (canvas->RenderGray(wanted, scale, &gray, &mask, &origin) && gray.cols >= 16 && gray.rows >= 16) {
    FeatureOptions more = extractor.options();
    more.max_features = 3 * more.max_features;  // the view is several frames large
    const FeatureExtractor wide(more);
    cv::Mat eroded;
    cv::erode(mask, eroded, cv::Mat(), cv::Point(-1, -1), 2);
    const Features mosaic = wide.ExtractScaled(pre.DetectionImage(gray, 1.0), scale, eroded);
    const cv::Matx33d crop_to_patch(1, 0, origin.x, 0, 1, origin.y, 0, 0, 1);
    const Matches m = MatchFeatures(*f, mosaic, extractor.options());
    Candidate c = Assess(EstimateEgomotion(m.from, m.to, K, ego_options), crop_to_patch, "patch_mosaic", -1);
    if (c.ego.ok) found.push_back(std::move(c));
  }
  lap(kRecovery);
  return found;
}

std::optional<Mosaicker::Impl::Candidate> Mosaicker::Impl::RecoverDensely(PreparedFrame& p, const Features& capped,
                                                                         const Matches* hint) {
  // Behind a live feed, two dense descriptions (0.1-0.25 s on the engine's thread) skipped the
  // frames after them: lanes-apart fed at 10 frames/s lost 5-9 frames of 150, none without.
  if (shedding || keys.empty() || static_cast<int>(capped.points.size()) < ExtractorFor(p).options().max_features)
    return std::nullopt;
  Key& key = keys.back();
  // A hint first: the features it has share a homography of a few inliers with the keyframe's.
  // Frames with nothing in common (the next lane apart) then cost a match, not two descriptions
  // (those made light-cone's and lanes-apart's lane starts 12 % slower to map).
  if (const auto& theirs = key.products.get().features) {
    const Matches m = hint ? *hint : MatchFeatures(capped, *theirs, extractor.options());
    if (m.from.size() < 8) return std::nullopt;
    std::vector<uchar> inliers;
    cv::findHomography(m.from, m.to, cv::USAC_MAGSAC, ego_options.homography_threshold_px, inliers, 2000, 0.999);
    if (std::count(inliers.begin(), inliers.end(), 1) < std::max(8, 2 * options.min_inliers / 5)) return std::nullopt;
  }
  if (!key.dense) {
    if (key.frame && key.frame->dense_features) {
      key.dense = key.frame->dense_features;  // it waited, and opened this patch
    } else {
      const cv::Mat& image = key.frame && !key.frame->image.empty() ? key.frame->image : key.products.get().image;
      if (image.empty() || image.size() != frame_size) return std::nullopt;
      key.dense = std::make_shared<const Features>(Describe(image, dense_extractor));
    }
  }
  if (!p.dense_features) p.dense_features = std::make_shared<const Features>(Describe(p.image, dense_extractor));
  const Matches m = MatchFeatures(*p.dense_features, *key.dense, dense_extractor.options());
  Candidate c = Assess(EstimateEgomotion(m.from, m.to, K, ego_options), key.to_patch, "dense_features", key.index);
  if (!c.ego.ok) return std::nullopt;
  return c;
}

// Only the frame right after a waiting one joins it; one placed after all (a second chance) no
// longer waits.
std::optional<FrameReport> Mosaicker::Impl::RecoverAcrossThinOverlap(const std::shared_ptr<PreparedFrame>& p,
                                                                     const Features& f, const Candidate& best,
                                                                     const FrameReport& r, const Matches* hint,
                                                                     Laps& lap) {
  const bool waits = !pending.empty() && pending.back().thin_overlap && pending.back().report.index == r.index - 1;
  if (waits) {
    // The frame after a thin overlap fails too: the waiting frame opens the next patch, joined
    // to this one, and this frame is tried against it.
    Pending w = std::move(pending.back());
    pending.pop_back();
    JoinAcrossThinOverlap(w.frame, *w.thin_overlap, Unreject(w.report));
    gate->Predict(StepsSinceLast(*p, r.index));
    Candidate again = Track(p, Start::kCorrelated);
    if (Usable(again)) return Place(p, std::move(again), r, lap);
    hint = nullptr;  // the last keyframe is now the one that waited
  }
  std::optional<Candidate> dense = RecoverDensely(*p, f, hint);
  lap(kRecovery);
  if (!dense || !Usable(*dense)) return std::nullopt;
  const std::string reason = best.ego.ok ? best.support.weakness : best.ego.failure;
  FrameReport lost = Lost(p, r, reason.empty() ? "thin_overlap" : reason);
  if (canvas && !pending.empty() && pending.back().report.index == r.index) pending.back().thin_overlap = std::move(dense);
  return lost;
}

// A strong registration stands even when unpredicted (a real change of course); a weak one (few
// or clustered inliers) only when the motion model, having learnt the motion, predicted it. While
// it learns (a patch's first frames) nothing vouches for a weak one: followed from a frame of
// open water, marine snow gave a plausible weak motion, and a patch of water (the test
// OpenWaterWithMarineSnowLeavesNoPatchOfWater); none of 24 spread surveys and 7 real sequences
// placed a frame so.
bool Mosaicker::Impl::Usable(const Candidate& c) const {
  if (!c.ego.ok) return false;
  if (c.support.strong) return true;
  if (!c.support.conditioned || !options.kalman) return false;
  return c.verdict.informed && c.verdict.consistent;
}

// Strong and predicted beats strong alone (a course change, or a texture that repeats turned
// about), which beats weak but predicted; among equals, the one closest to the prediction.
const Mosaicker::Impl::Candidate* Mosaicker::Impl::Pick(const std::vector<Candidate>& all) const {
  auto rank = [](const Candidate& c) { return c.support.strong ? (c.verdict.consistent ? 3 : 2) : 1; };
  const Candidate* pick = nullptr;
  for (const auto& c : all) {
    if (!Usable(c)) continue;
    if (!pick || rank(c) > rank(*pick) || (rank(c) == rank(*pick) && c.verdict.distance2 < pick->verdict.distance2))
      pick = &c;
  }
  return pick;
}

EgomotionResult Mosaicker::Impl::RegisterPair(PreparedFrame& frame, PreparedFrame& onto,
                                              std::optional<std::vector<cv::Point2f>>* onto_corners) {
  const auto a = FeaturesOf(frame), b = FeaturesOf(onto);
  EgomotionResult by_features;
  if (a && b && a->strong >= options.min_inliers && b->strong >= options.min_inliers) {
    const Matches m = MatchFeatures(*a, *b, extractor.options());
    by_features = EstimateEgomotion(m.from, m.to, K, ego_options);
    if (by_features.ok && AssessSupport(by_features, frame_size, support_options).strong) return by_features;
  }
  if (!onto.track || !frame.track) return by_features;
  std::optional<std::vector<cv::Point2f>> found;
  if (!onto_corners) onto_corners = &found;
  if (!*onto_corners) *onto_corners = tracker.Corners(*onto.track, {}, track_points);
  EgomotionResult followed = FollowInto(onto, frame, **onto_corners);
  if (followed.ok && AssessSupport(followed, frame_size, support_options).strong) return followed;
  return by_features.ok ? by_features : followed;
}

EgomotionResult Mosaicker::Impl::FollowInto(const PreparedFrame& from, const PreparedFrame& to,
                                            const std::vector<cv::Point2f>& corners) const {
  double response = 0;
  const cv::Matx33d guess = tracker.CoarseShift(*from.track, *to.track, cv::Matx33d::eye(), &response);
  const TrackFlow flow = tracker.Follow(*from.track, *to.track, corners, guess);
  std::vector<cv::Point2f> in_to, in_from;
  flow.Kept(corners, &in_to, &in_from);
  return EstimateEgomotion(in_to, in_from, K, ego_options);
}

FrameReport Mosaicker::Impl::JoinAcrossThinOverlap(const std::shared_ptr<PreparedFrame>& p, const Candidate& c,
                                                   FrameReport r) {
  r.matches = c.ego.matches;
  r.inliers = c.ego.inliers;
  r.bilateral_error = c.ego.bilateral_error_mean;
  // Adjusted with the patch it leaves as its closing frame, a leaf on one link: it cannot bend
  // the frames before it.
  OpenJoinedPatch(p, r, c.to_patch, c.Links(r.index), "thin_overlap");
  frames.back().registered_by = c.registered_by;
  return r;
}

void Mosaicker::Impl::OpenJoinedPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport& r,
                                      const cv::Matx33d& to_patch, std::vector<FrameLink> links,
                                      const std::string& why) {
  ClosingFrame closing;
  closing.index = r.index;
  closing.to_patch = to_patch;
  closing.links = std::move(links);
  PatchLink join;
  join.previous_patch = patch_id;
  link_to_first = to_patch;  // the closing frame is the next patch's first
  // Frames waiting for a second chance wait on in the next patch and are tried against its first
  // frame at once: a lane's first frame, rejected, overlaps the second most, and when the budget
  // closed the patch at that second frame the first was lost (lawnmowers joined without turns).
  ClosePatch(why, closing);
  StartPatch(p, r, join);
  Laps lap{this, {}};
  SecondChance(p, cv::Matx33d::eye(), lap);
}

// Frames rejected earlier in this patch, tried again against the frame just placed (RegisterPair):
// a frame that failed against its predecessor (blur, a passing fish) often matches its
// successor, and a lane's dark first frames the one that starts it.
void Mosaicker::Impl::SecondChance(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch, Laps& lap) {
  if (pending.empty()) return;
  std::optional<std::vector<cv::Point2f>> corners;  // of `p`, found once for all the waiting frames
  for (auto it = pending.begin(); it != pending.end();) {
    // Linked to the frame it was registered onto when that is a keyframe (the adjustment's
    // frames); else tied by its placement.
    Candidate c = Assess(RegisterPair(*it->frame, *p, &corners), to_patch, "second_chance",
                         last.keyframe ? last.index : -1);
    if (!c.support.strong) {
      it = ++it->tries >= 2 ? pending.erase(it) : std::next(it);
      continue;
    }
    // Where the patch image has no room left for it (the budget reached beside the lane) it is
    // placed, described and linked all the same, and left out of the patch image (`blended`
    // false): dropped, it was a frame of the survey missing from the map (a lane's first frame,
    // 102 inliers onto the second, lost on 640 x 480 stills; bench/RESULTS.md, session 49).
    const bool blend = canvas->Fits(PatchCanvas::FrameBounds(c.to_patch, frame_size));
    FrameReport r = Unreject(it->report);
    r.matches = c.ego.matches;
    r.inliers = c.ego.inliers;
    FrameRecord rec = RecordOf(r, c.to_patch);
    rec.registered_by = "second_chance";
    AddKeyframe(it->frame, c.to_patch, nullptr, c.Links(r.index), std::move(rec), false, blend);
    it = pending.erase(it);
  }
  lap(kRecovery);
}

}  // namespace rolamos
