#include "rolamos/mosaicker.hpp"

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
#include "store/writer_lock.h"
#include "util/cpu_time.h"
#include "util/files.h"
#include "util/homography.h"
#include "util/memory.h"
#include "util/task_pool.h"

namespace rolamos {

namespace {

// The working canvas (refinement and recovery against the patch) at half resolution: a quarter
// of the blending work; the patch image is blended at full resolution when it closes.
constexpr double kWorkingScale = 0.5;

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
// or clustered inliers) stands when the motion model predicted it, or, while the model is still
// learning, when it is a plausible motion from the frame followed (a patch's first frames).
bool Mosaicker::Impl::Usable(const Candidate& c) const {
  if (!c.ego.ok) return false;
  if (c.support.strong) return true;
  if (!c.support.conditioned || !options.kalman) return false;
  return c.verdict.informed ? c.verdict.consistent : c.tracked();
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
  std::vector<cv::Point2f> src, dst;
  std::vector<int> owner;
  std::vector<cv::Point2f> theirs;
  const Key& key = keys.back();
  for (size_t i = 0; i < c.ego.inlier_from.size(); ++i) {
    src.push_back(c.ego.inlier_from[i]);
    dst.push_back(cv::Point2f(ApplyHomography(key.to_patch, c.ego.inlier_to[i])));
    theirs.push_back(c.ego.inlier_to[i]);
    owner.push_back(key.index);
  }
  int used = 0;
  for (auto it = keys.rbegin() + 1; it != keys.rend() && used < 2; ++it) {
    if (!it->frame || !it->frame->track) break;  // no longer kept: older ones are not either
    if (FootprintOverlap(guess, it->to_patch, frame_size) < 0.3) continue;
    const TrackFlow flow =
        tracker.Follow(*it->frame->track, *p.track, it->points, guess.inv() * it->to_patch, it->windows.get());
    int n = 0;
    for (size_t i = 0; i < it->points.size(); ++i) {
      if (!flow.ok[i]) continue;
      src.push_back(flow.to[i]);
      dst.push_back(cv::Point2f(ApplyHomography(it->to_patch, it->points[i])));
      theirs.push_back(it->points[i]);
      owner.push_back(it->index);
      ++n;
    }
    if (n >= 8) ++used;
  }
  if (used == 0) return guess;
  // Least squares with outliers trimmed, from the guess.
  cv::Matx33d H = guess;
  std::vector<uchar> keep(src.size(), 1);
  for (int round = 0; round < 3; ++round) {
    std::vector<double> res(src.size());
    for (size_t i = 0; i < src.size(); ++i) res[i] = cv::norm(ApplyHomography(H, src[i]) - cv::Point2d(dst[i]));
    std::vector<double> sorted = res;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double cut = std::max(fit_options.inlier_px, 3.0 * sorted[sorted.size() / 2]);
    std::vector<cv::Point2f> a, b;
    for (size_t i = 0; i < src.size(); ++i) {
      keep[i] = res[i] <= cut;
      if (!keep[i]) continue;
      a.push_back(src[i]);
      b.push_back(dst[i]);
    }
    if (a.size() < 12) return guess;
    const cv::Mat refined = cv::findHomography(a, b, 0);
    if (refined.empty()) return guess;
    H = cv::Matx33d(refined);
    H *= 1.0 / H(2, 2);
  }
  if (MaxCornerShift(H, guess, frame_size) > fit_options.max_correction_px ||
      !IsPlausibleMotion(last.to_patch.inv() * H, frame_size, support_options))
    return guess;
  std::map<int, FrameLink> by_frame;
  for (size_t i = 0; i < src.size(); ++i) {
    if (!keep[i]) continue;
    FrameLink& l = by_frame[owner[i]];
    l.b = owner[i];
    l.in_a.push_back(src[i]);
    l.in_b.push_back(theirs[i]);
  }
  fitted->clear();
  for (auto& [who, l] : by_frame)
    if (l.in_a.size() >= 8) fitted->push_back(std::move(l));
  *frames_used = 1 + used;
  return H;
}

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
