// Mosaicker's state and stages, private to src/engine: the struct the public class hides. Its
// member functions are defined by stage: mosaicker.cc (a frame's way through the engine, the
// public calls), mosaicker_registration.cc (a frame followed from the keyframe, recovered by SIFT,
// given a second chance), mosaicker_keyframes.cc (keyframes: fitted, described, linked, blended)
// and mosaicker_patches.cc (patches opened, closed, broken and dropped).
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/colour.h"
#include "engine/ecc_refine.h"
#include "engine/egomotion.h"
#include "engine/feather.h"
#include "engine/features.h"
#include "engine/grey.h"
#include "engine/keyframe_job.h"
#include "engine/lucas_kanade.h"
#include "engine/motion_gate.h"
#include "engine/patch_adjustment.h"
#include "engine/patch_canvas.h"
#include "engine/patch_writer.h"
#include "engine/prepared_frame.h"
#include "engine/preprocess.h"
#include "engine/registration.h"
#include "engine/stage_options.h"
#include "engine/static_mask.h"
#include "engine/tracker.h"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "store/writer_lock.h"
#include "util/cpu_time.h"
#include "util/files.h"
#include "util/homography.h"
#include "util/memory.h"
#include "util/task_pool.h"

namespace rolamos {

struct Mosaicker::Impl {
  // Held from before anything is written until the last patch is (Finish): one engine a store.
  std::unique_ptr<StoreWriterLock> writer_lock;
  MosaickerOptions options;
  Store store;
  Preprocessor pre;
  FeatureExtractor extractor;
  // SIFT without the doubled first octave, for keyframes that are not blended (coarse_features).
  FeatureExtractor coarse_extractor;
  // Both with fewer features, for keyframes that frames were followed into (followed_features).
  FeatureExtractor followed_extractor, coarse_followed_extractor;
  // Recovery's last try, on frames that overlap little: three times the features.
  FeatureExtractor dense_extractor;
  FrameTracker tracker;
  EgomotionOptions ego_options;
  EccOptions ecc_options;
  SupportOptions support_options;
  PatchFitOptions fit_options;
  PatchAdjustmentOptions adjust_options;
  std::unique_ptr<ColourModel> colour;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  double cpu_start = ProcessCpuSeconds();

  // The first frame fixes the size and the camera.
  cv::Size frame_size;
  int track_points = 0;  // what a keyframe hands on at this frame size (InitCamera)
  cv::Matx33d K = cv::Matx33d::eye();
  std::shared_ptr<const FeatherCode> weights;
  // Static overlays: 255 where the frame is usable (full size), and at the detection scale.
  std::mutex mask_mutex;
  std::string mask_path;  // options.mask, or a mask given mid-run (UseMask)
  cv::Mat usable, usable_small;
  long mask_generation = 0;  // counts the changes of usable_small (features found ahead check it)
  std::atomic<bool> mask_changed{false};  // the blending weights are made again at the next frame
  std::unique_ptr<MotionGate> gate;
  // A frame of another size waits here: a second one like it means the camera changed for good.
  std::shared_ptr<PreparedFrame> resized;
  FrameReport resized_report;

  // A keyframe of the open patch.
  struct Key {
    int index = 0;
    cv::Matx33d to_patch = cv::Matx33d::eye();
    std::shared_ptr<PreparedFrame> frame;  // kept while recent: followed from, fitted against
    std::vector<cv::Point2f> points;       // followed into the frames after it
    std::vector<long long> ids;            // their tracks
    // The frame's windows around `points`, made on the first follow from them (tracker.h), here
    // or in its job (KeyframeJob::windows).
    std::shared_ptr<SharedWindows> windows = std::make_shared<SharedWindows>();
    KeyframeFuture products;
    bool described = true;                 // its features are found (products.features)
    bool blended = true;                   // in the patch image (else it links and places only)
    bool still = false;                    // taken right after another keyframe (StillKeyframe)
    std::shared_ptr<const Features> dense;  // found when recovery first needs them (RecoverDensely)
  };
  // The frame placed last, keyframe or not.
  struct Placed {
    int index = -1;
    cv::Matx33d to_patch = cv::Matx33d::eye();
    std::shared_ptr<PreparedFrame> frame;
    bool keyframe = false;
    std::vector<FrameLink> links;  // a followed frame's tracks with its keyframe
    bool blended = false;
    bool still = false;  // a keyframe taken right after another (MosaickerOptions::still_*)
  };

  // The frames followed from the current keyframe (MosaickerOptions::follow_back): the next
  // keyframe's job registers them against it too (a bounded sample of them).
  FollowedSample followed_since_key;
  // The patch in progress.
  std::unique_ptr<PatchCanvas> canvas;
  int patch_id = 0;
  int next_patch_id = 1;  // patches are committed later, by the writer thread
  std::vector<FrameRecord> frames;       // frame_to_patch in first-frame coordinates until closed
  std::vector<RejectedFrame> rejected;
  std::optional<PatchLink> link;         // how this patch joins the one before
  cv::Matx33d link_to_first = cv::Matx33d::eye();  // with a link: this patch -> the previous one's first frame
  std::vector<Key> keys;
  std::vector<FrameLink> links;          // between keyframes, from their tracks
  size_t keyframe_bytes = 0;                // keyframes' images and features held until the patch is written
  // What a keyframe holds until its patch is written: its filtered image when blended, its
  // features when described.
  size_t KeyframeBytes(const PreparedFrame& p, bool described = true, bool blended = true) const {
    return (blended ? p.image.total() * p.image.elemSize() : 0) +
           (described ? size_t(options.max_features) * 128 * sizeof(float) : 0);
  }
  Placed last;
  // Load shedding (Mosaicker::ShedLoad): fewer keyframes described.
  bool shedding = false;
  double shed_describe_overlap = 0.5;
  // The camera's frames so far, those a live source skipped included (PreparedFrame::camera_frame).
  long camera_frames = 0;
  // Camera frames from the last frame placed to `p` (the `index`-th integrated): the motion
  // model's gap, which frames a live source skipped widen.
  int StepsSinceLast(const PreparedFrame& p, int index) const {
    if (!last.frame) return index - last.index;
    return static_cast<int>(std::clamp<long>(p.camera_frame - last.frame->camera_frame, 1, 1 << 20));
  }
  // Features found ahead (MosaickerOptions::features_ahead): asked of the preparing threads while
  // the last frames all needed theirs (described keyframes, recovery) and one of the last few
  // needed them on this thread. Frames that only follow (video) need none.
  std::atomic<bool> features_ahead{false};
  std::atomic<int> features_ahead_used{0};
  int wanted_run = 0;                 // frames in a row whose features were needed
  int since_needed_here = 1 << 20;   // frames since one's features were needed on this thread
  bool wanted_now = false, needed_here_now = false, keyframed_now = false;  // the frame being integrated
  // After each frame: features found ahead that nothing will ask for (a frame placed without
  // becoming a keyframe: only this thread reads its features) are let go.
  void NoteFeaturesNeeded(PreparedFrame& p) {
    if (!keyframed_now) p.ahead.reset();
    wanted_run = wanted_now ? wanted_run + 1 : 0;
    since_needed_here = needed_here_now ? 0 : std::min(since_needed_here + 1, 1 << 20);
    wanted_now = needed_here_now = keyframed_now = false;
    features_ahead = options.features_ahead && wanted_run >= 4 && since_needed_here < 8;
  }
  long long next_track = 0;
  int lost = 0;
  // The last frame rejected (-1: none, or placed after all), and whether the open patch's first
  // frame came right after one (or first in a run whose tracking was then lost): IsolatedPatch.
  int last_rejected = -1;
  bool opened_in_loss = false;
  MosaicSummary summary;

  // Stage timers, in the order of the pipeline; nanoseconds, added atomically (several threads).
  enum Stage { kPreprocess, kTracking, kEgomotion, kFeatures, kRecovery, kKeyframeFit, kEcc, kCanvas, kFilter,
               kLoopLinks, kStages };
  std::atomic<long long> stage_ns[kStages] = {};
  // CPU time of the calling thread: each stage's own cost, not its waits for a core.
  struct Laps {
    Impl* m;
    CpuLaps cpu;
    void operator()(Stage s) { m->stage_ns[s] += cpu.Lap(); }
    void Restart() { cpu.Restart(); }
  };

  PatchWriter writer;
  // Keyframes' filtering, features and loop links, off the engine's thread; a few may wait.
  TaskPool keyframe_pool{2, 4};

  Impl(Store s, const MosaickerOptions& o)
      : writer_lock(LockStoreForChange(s, "a rolamos mosaic engine")),
        options(o),
        store(s),
        pre(ToPreprocessOptions(o)),
        extractor(ToFeatureOptions(o)),
        coarse_extractor(CoarseFeatureOptions(o)),
        followed_extractor(FollowedFeatureOptions(ToFeatureOptions(o), o)),
        coarse_followed_extractor(FollowedFeatureOptions(CoarseFeatureOptions(o), o)),
        dense_extractor(DenseFeatureOptions(o)),
        tracker(ToTrackerOptions(o)),
        ego_options(ToEgomotionOptions(o)),
        ecc_options(ToEccOptions(o)),
        writer(s, o.tiff) {
    adjust_options = ToPatchAdjustmentOptions(o);
    ColourOptions co;
    co.lighting = o.flat_field;
    co.exposure = o.exposure;
    co.water_colour = o.water_colour;
    colour = std::make_unique<ColourModel>(co);
  }
  ~Impl() {
    try {
      keyframe_pool.Wait();
    } catch (...) {
    }
  }

  // A candidate placement of the frame in the patch, and what supports it.
  struct Candidate {
    EgomotionResult ego;  // from the frame to what it was registered against
    cv::Matx33d to_patch = cv::Matx33d::eye();
    Support support;
    GateVerdict verdict;
    std::string registered_by;  // "" = followed from the keyframe
    int target = -1;            // the frame it was registered against (-1: the patch image)
    // Tracks followed into the frame that agree with the registration (when followed).
    std::vector<long long> ids;
    std::vector<cv::Point2f> at;
    bool tracked() const { return registered_by.empty(); }
    std::vector<FrameLink> Links(int index) const {
      if (target < 0 || !ego.ok) return {};
      return {FrameLink{index, target, ego.inlier_from, ego.inlier_to}};
    }
  };
  // Frames rejected while this patch is open, kept for a second chance against later frames and
  // to start the next patch from when tracking breaks.
  struct Pending {
    std::shared_ptr<PreparedFrame> frame;
    FrameReport report;
    int tries = 0;
    // Registered only across a thin overlap (RecoverDensely), and rejected for now: the usual
    // recovery of the frame after it often places both within the patch (lanes joined without a
    // turn). It opens the next patch, joined by this, only when the next frame fails too.
    std::optional<Candidate> thin_overlap;
    // Frames after it it was tried against to start the next patch (BreakAt). A lane's first
    // frame pairs with the first frame after it or not at all (every such pairing on 34 spread
    // and seed surveys); open water never pairs, and each try costs a registration.
    int break_tries = 0;
  };
  std::deque<Pending> pending;

  void InitCamera(cv::Size size);
  std::shared_ptr<const Features> FeaturesOf(PreparedFrame& p);
  // The frame's features by `ex`, without the static overlays and the specks the detection image
  // leaves out.
  // `mask_seen`: the generation of the overlay mask the features were found with.
  Features Describe(const cv::Mat& image, const FeatureExtractor& ex, long* mask_seen = nullptr);
  // Recovery's last try: the frame and the last keyframe described three times as densely.
  // `hint`: the frame's own features matched with the last keyframe's, when Recover did that.
  std::optional<Candidate> RecoverDensely(PreparedFrame& p, const Features& capped, const Matches* hint);
  // A frame of another size than the survey's: a report when that is all it gets (rejected, or
  // opening the patch of the new size), none when it goes on into the patch just opened.
  std::optional<FrameReport> FollowSizeChange(const std::shared_ptr<PreparedFrame>& p, FrameReport& r);
  FrameReport OpenPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport r, Laps& lap);
  // The frame nothing else placed, across a thin overlap (Integrate's step 3): a report when it
  // was placed or waits, none when it is lost the usual way.
  std::optional<FrameReport> RecoverAcrossThinOverlap(const std::shared_ptr<PreparedFrame>& p, const Features& f,
                                                      const Candidate& best, const FrameReport& r, const Matches* hint,
                                                      Laps& lap);
  // The patch closes (`why`) with frame `p` as its closing frame, placed at `to_patch` and adjusted
  // with its keyframes through `links`; `p` opens the next patch, linked to this one through it.
  void OpenJoinedPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport& r, const cv::Matx33d& to_patch,
                       std::vector<FrameLink> links, const std::string& why);
  // The frame `c` placed across a thin overlap opens the next patch, joined to this one by `c`.
  FrameReport JoinAcrossThinOverlap(const std::shared_ptr<PreparedFrame>& p, const Candidate& c, FrameReport r);
  // SIFT as the frame asks: halved (coarse_features), fewer (followed_features), both or neither.
  const FeatureExtractor& ExtractorFor(const PreparedFrame& p) const;
  FrameMotion MotionFromLast(const cv::Matx33d& to_patch) const {
    return MotionOf(last.to_patch.inv() * to_patch, frame_size);
  }
  Candidate Assess(EgomotionResult ego, const cv::Matx33d& target_to_patch, const std::string& by, int target);
  // Where following starts: where the motion model expects the frame, that moved by a coarse
  // correlation, or where the last frame was, moved by the correlation (the model overshot), or
  // that turned by what correlates best (a turn nothing foresaw: FrameTracker::CoarseTurn).
  enum class Start { kPredicted, kCorrelated, kUnmoved, kTurned };
  // A follow tried for the frame being integrated, under the motion model's present prediction.
  struct Tried {
    Start start;
    cv::Matx33d guess;
    Candidate result;
    bool cut_short = false;  // its follow gave up after its sample
  };
  // `tried` (optional): the follows tried before under the same prediction; one from the same
  // guess is not followed again (the same inputs give the same candidate), and this one is added.
  // `may_give_up`: the follow gives up after a sample that failed (FrameTracker::Follow); else a
  // follow tried before that gave up is followed whole.
  Candidate Track(const std::shared_ptr<PreparedFrame>& p, Start start, std::vector<Tried>* tried = nullptr,
                  bool may_give_up = false);
  // 1. in Integrate: the frame followed from each start in turn until one holds; `far`:
  // PredictionFarOff's answer for it.
  Candidate FollowStarts(const std::shared_ptr<PreparedFrame>& p, bool far, std::vector<Tried>* tried,
                         bool may_give_up);
  // Where following starts (key -> frame pixels), before any correlation: the last frame's
  // place, moved by the motion model's prediction unless the start is from the last frame.
  cv::Matx33d StartGuess(Start start) const;
  // The coarse correlation's shift of `guess` for the frame being integrated: made once a frame
  // (the predicted and correlated starts share it), kept in `correlated`.
  struct Correlated {
    long frame = -1, key = -1;  // the frame (summary.frames when it was integrated), the keyframe
    cv::Matx33d guess, shifted;
    double response = 0;
  };
  Correlated correlated;
  const Correlated& Correlate(const PreparedFrame& p, const cv::Matx33d& guess);
  // Whether the predicted start is so far from where the frame correlates that following from
  // it is not worth trying first (see kFarShiftPx). Asked only while predictions have been
  // failing (jittered stills), so frames the model foresees (video) pay no correlation.
  bool PredictionFarOff(const PreparedFrame& p);
  int since_prediction_failed = 1 << 20;  // frames since the predicted start did not hold
  // `with_last_key`: set to the frame's matches with the last keyframe when they were made.
  std::vector<Candidate> Recover(const std::shared_ptr<PreparedFrame>& p, Laps& lap,
                                 std::optional<Matches>* with_last_key = nullptr);
  bool Usable(const Candidate& c) const;
  // Usable, strong and what the motion model expects: nothing else need be tried.
  bool Settled(const Candidate& c) const { return Usable(c) && c.support.strong && c.verdict.consistent; }
  const Candidate* Pick(const std::vector<Candidate>& all) const;
  bool WantsKeyframe(const Candidate& c, const cv::Matx33d& to_patch) const;
  // Whether a new keyframe is described (MosaickerOptions::describe_overlap, still_describe_overlap).
  bool Describes(const PreparedFrame& p, const cv::Matx33d& to_patch, const Candidate* c, bool still) const;
  // Whether a new keyframe is blended (MosaickerOptions::blend_overlap, still_blend_overlap).
  bool Blends(const Candidate& c, const cv::Matx33d& to_patch) const;
  // It overlaps the last blended keyframe by `overlap` or more.
  bool WouldOnlyLink(const cv::Matx33d& to_patch, double overlap) const;
  // Frames were followed (placed between keyframes) since the last keyframe: video, not stills.
  bool FollowedSinceKeyframe() const { return !last.keyframe; }
  // The frame being placed at `to_patch` becomes a keyframe right after another that it overlaps
  // less than keyframe_overlap (MosaickerOptions::still_*): stills, too far apart to be followed
  // between keyframes. Not a video's keyframes taken one after another where its points thinned
  // out or its registration was doubtful (roll and pitch jittered, turns), 95 % apart. Always
  // false while the still_* options treat stills as any keyframe (the default): no overlap is
  // measured for them then.
  bool StillKeyframe(const cv::Matx33d& to_patch) const {
    return StillsDiffer() && last.frame && !FollowedSinceKeyframe() &&
           FootprintOverlap(to_patch, last.to_patch, frame_size) < options.keyframe_overlap;
  }
  bool StillsDiffer() const {
    return options.still_track_points > track_points || options.still_describe_overlap < 1.0 ||
           StillBlendRule();
  }
  cv::Matx33d FitToKeyframes(const PreparedFrame& p, const Candidate& c, std::vector<FrameLink>* fitted, int* frames);

  void StartPatch(const std::shared_ptr<PreparedFrame>& p, FrameReport& r, const std::optional<PatchLink>& join);
  // The patch closes (`why`, with its closing frame if any). The frames waiting for a second
  // chance, and their rejections, go on with whatever comes next, which they may yet join; only
  // the end of the run and a new frame size give them up (DropWaiting first), their rejections
  // then listed in the patch that closes.
  void ClosePatch(const std::string& why, const std::optional<ClosingFrame>& closing = std::nullopt);
  void DropWaiting() { pending.clear(); }
  // The open patch's canvas, frames, keyframes and links gone (written, or dropped); its
  // rejections and the frames waiting stay.
  void ForgetPatch();
  // A patch of one frame that nothing joined, opened right after a rejected frame and followed
  // by rejected ones (or by the end of the run): open water or nothing in view (an ROV's descent
  // and ascent, a burst of black frames).
  // Written, each would be a tile of water placed beside the map: one every four frames of a
  // descent (max_lost_frames + 1). Its frame is rejected instead ("isolated").
  bool IsolatedPatch(const std::string& why) const;
  void DropIsolatedPatch();
  // Frames rejected after the last patch closed (the run ended over open water, in black
  // frames): no patch opened to list them, so the last one written does. None written: the
  // summary alone counts them.
  void ListLateRejections();
  // `current`: the frame the next ones are followed from (false: a frame placed late, behind it).
  void AddKeyframe(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch, const Candidate* c,
                   std::vector<FrameLink> found, FrameRecord rec, bool current = true, bool blend = true);
  // The keyframes a new one is matched with (features, guided by the placements) for the
  // adjustment: the recent ones it overlaps besides the one it was followed from (independent
  // measurements over longer baselines, so error does not add up along a lane), and the older
  // ones under it (an earlier lane: loop closures).
  std::vector<OlderKeyframe> LinkCandidates(const cv::Matx33d& to_patch, bool current) const;
  // The first of the recent keyframes (PatchFitOptions::recent_frames) a new keyframe is fitted
  // against; those before it are linked by loop closures only.
  size_t FirstRecentKey(bool current) const;
  // The described keyframes before the recent ones that lie under a new keyframe (the lane
  // before), most overlapped first: its loop closures' candidates, which only SIFT's features link.
  std::vector<std::pair<double, const Key*>> OlderUnder(const cv::Matx33d& to_patch, bool current) const;
  // A rejected frame stitched after all: out of the rejected list, counted as recovered.
  void AddFollowed(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch, FrameRecord rec,
                   std::vector<FrameLink> links);
  // The last frame placed becomes a keyframe when the patch closes after it (lost tracking, end
  // of input): the patch reaches as far as the frames it placed, and its features are stored.
  void PromoteLast();
  // The last frame placed was followed (not a keyframe) and can hand on points: a frame that
  // its keyframe does not hold may be followed from it instead (Integrate, step 1).
  bool LastCanBeKeyframe() const { return LastIsOpenPatchsNewest() && !last.keyframe && last.frame->track; }
  // The last frame placed is the open patch's newest frame (not one placed late, behind it).
  bool LastIsOpenPatchsNewest() const {
    return canvas && last.frame && !frames.empty() && frames.back().index == last.index;
  }
  void BlendLastKeyframe();
  // The last frame is a still not blended that the blended keyframes before it and `next` (the
  // frame placed after it, when blended) leave part of uncovered: a lane's last still, a turn.
  // It is blended after all, or the patch image would have a hole there.
  bool LastStillUncovered(const cv::Matx33d* next) const;
  // Stills are blended more sparsely than other keyframes (still_blend_overlap below blend_overlap).
  bool StillBlendRule() const { return options.still_blend_overlap < options.blend_overlap; }
  void AddToCanvas(const PreparedFrame& p, const cv::Matx33d& to_patch);
  FrameReport Reject(FrameReport r, const std::string& reason);
  FrameReport Lost(const std::shared_ptr<PreparedFrame>& p, FrameReport r, const std::string& reason);
  bool BreakAt(const std::shared_ptr<PreparedFrame>& p);
  // `frame` registered onto `onto` (frame pixels -> onto's pixels), two frames the patch's tracks
  // do not join: by SIFT when both have features enough, otherwise or when that is not strong by
  // following `onto`'s corners into it (FollowInto). `onto_corners` keeps those corners for the
  // next frame registered onto the same one (SecondChance tries several).
  EgomotionResult RegisterPair(PreparedFrame& frame, PreparedFrame& onto,
                               std::optional<std::vector<cv::Point2f>>* onto_corners = nullptr);
  // `corners` of `from` followed into `to`, from a coarse correlation: `to` pixels -> `from`'s.
  EgomotionResult FollowInto(const PreparedFrame& from, const PreparedFrame& to,
                             const std::vector<cv::Point2f>& corners) const;
  void SecondChance(const std::shared_ptr<PreparedFrame>& p, const cv::Matx33d& to_patch, Laps& lap);
  FrameReport Place(const std::shared_ptr<PreparedFrame>& p, Candidate best, FrameReport r, Laps& lap);
  FrameRecord RecordOf(const FrameReport& r, const cv::Matx33d& to_patch) const;
  // A rejected frame placed after all: out of the rejected list, counted as recovered; its report
  // as stitched.
  FrameReport Unreject(const FrameReport& rejected);
  // The overlay mask at full size (empty when there is none), from any thread.
  cv::Mat Usable() {
    std::lock_guard<std::mutex> lock(mask_mutex);
    return usable;
  }
  // Feathering weights for the frame size, zero on the overlay mask: overlays never blend.
  void MakeWeights() {
    cv::Mat w = FeatherWeights(frame_size, options.feather_sigma);
    const cv::Mat u = Usable();
    if (!u.empty() && u.size() == frame_size) w.setTo(0, u == 0);
    weights = std::make_shared<const FeatherCode>(w);
  }
};

}  // namespace rolamos
