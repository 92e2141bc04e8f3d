// The online ROLAMOS engine: frames are pushed one at a time. Every frame is followed from the
// current keyframe (pyramidal Lucas-Kanade tracks; the paper's F-RANSAC with the bilateral
// epipolar error, the homography and its decomposition on them) and checked by the Kalman gate;
// when following fails, SIFT features recover it against the patch. Keyframes (chosen by
// predicted overlap) are refined by ECC against the patch, filtered (spatio-temporal, bilateral),
// described by SIFT for the global map, and blended with Gaussian feathering; the frames between
// them are placed only. A patch is closed and written to the store (in a background thread:
// adjustment of its keyframes, full-resolution blending) when the next keyframe would take it
// past its pixel budget or tracking is lost.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct PreparedFrame;  // a frame after pre-processing and feature extraction
struct Features;       // a frame's keypoints and descriptors

struct MosaickerOptions {
  // 1. Pre-processing
  // OpenCV calibration file; "" = frames already rectified; "auto" = estimate radial distortion
  // from the first frames (MosaicInput writes it to <store>/calibration.yml)
  std::string calibration;
  // Without a calibration file: the camera's horizontal field of view in water, degrees (the
  // camera each frame is placed through when a patch is adjusted).
  double fov_deg = 70;
  bool bilateral = true;
  bool temporal = true;
  bool clahe = true;            // detection image only
  // Static overlays (timestamp, laser dots, housing) left out of matching, ECC and blending:
  // an image of the frames' size, white where the frames hold a fixed overlay; "" = none;
  // "auto" = found from the first frames, or the frames after them where the seafloor hardly
  // moves under those (a descent through open water); MosaicInput writes it to
  // <store>/static_mask.png.
  std::string mask = "auto";
  // 2. Egomotion. Every frame is followed from the current keyframe with pyramidal Lucas-Kanade
  // (forward and backward), the homography and the paper's F-RANSAC / bilateral check fitted to
  // the tracks; features (SIFT) are found only on keyframes (stored for the global map) and for
  // recovery.
  // Frames are followed halved until the tracking image holds at most this many pixels.
  double track_pixels = 0.6e6;
  // Frames halved at least once all the same (unless under 0.4 of track_pixels): "always" (frames
  // from a video codec: its blocks and lost detail are followed better over twice the ground,
  // and a quarter of the pyramid), "never" (stills: their fine detail places them better), or
  // "auto": always for a video file or stream, never for images (MosaicInput and MosaicLive
  // decide from the input; frames pushed one by one count as images).
  std::string track_halve = "auto";
  // A video's frames, halved once by track_halve, are then halved until they hold at most this
  // many pixels (or track_pixels, the smaller): 1292 x 964 and 1920 x 1080 at a quarter,
  // 1280 x 720 and smaller at half. A codec leaves large frames little fine detail to follow: at
  // a quarter, with twice the track_points, they are followed better at about the same speed
  // (bench/RESULTS.md, session 17; a near-lossless stream loses a little).
  double video_track_pixels = 0.25e6;
  int track_points = 300;       // points a keyframe hands on (twice as many on video followed at a quarter)
  // Lucas-Kanade's window, tracking pixels, for frames followed at full size (frames followed
  // halved, stills beyond track_pixels and a video's, use 21; a video followed at a quarter 13).
  // 31 averages a point's place over twice the pixels of 21: the tracks' pairs 15-25 % nearer the
  // truth, 34 surveys 11 % truer within each patch and 9 % after align, 0-7 % more
  // CPU (bench/RESULTS.md, sessions 49-50). A still its keyframe holds too thinly for the wider
  // window is followed from the frame after that keyframe (made one) instead.
  int track_window = 31;
  // A frame turned more than this (degrees) from the frame it is followed from is followed in a
  // copy warped back by the predicted motion (Lucas-Kanade's windows do not turn). 0 = never.
  double track_turn_deg = 2.0;
  // A frame no start above followed (the motion model's, a coarse correlation's, the last
  // frame's place) is tried once more before SIFT recovery, turned by what correlates best
  // within this many degrees either way of the last frame (84 is enough for any turn a still
  // makes). A random walk's stills turn by up to 40 degrees, which nothing foresees: 300 stills,
  // 133 -> 56 recovered, 0.237 -> 0.218 px per patch, and the 1920 x 1080 turns better too; but
  // the global map after `align` is worse (a lawnmower's turns 0.15 -> 0.18 px, a random walk
  // 0.47 -> 0.49: the frames it follows are no longer recovered keyframes with SIFT's links).
  // Off by default, for maps read patch by patch (bench/RESULTS.md, session 33). 0 = not tried.
  double track_turn_search_deg = 0.0;
  // A frame becomes a keyframe (adjusted with the patch's others, its features stored) when its
  // overlap with the last keyframe falls below this, when the next frame is predicted to fall
  // below keyframe_min_overlap, when the registration is doubtful or came from recovery, or when
  // the points followed thin out. 1 = every frame is a keyframe. Dense keyframes hold a patch
  // straight: on MPEG-4 video at 800 x 600, 0.85 against 0.75 (with blend_overlap 0.75) takes
  // the per-patch error from 0.90 to 0.64 px at the same CPU (nine surveys, bench/RESULTS.md).
  // Stills at 70 % overlap are keyframes, and blended, either way.
  double keyframe_overlap = 0.85;
  double keyframe_min_overlap = 0.5;
  // A frame followed between two keyframes is registered against the next one too (that
  // keyframe's points followed back into it, on the keyframe workers) and placed where the two
  // registrations put it, each weighted by its inliers: two independent measurements of a frame
  // whose own error goes with its support. On video, 5-23 % less error per patch for 2-11 % of
  // the frames a second (bench/RESULTS.md, session 24); stills have no followed frames.
  bool follow_back = true;
  // A keyframe is blended into the patch image (after the spatio-temporal filter and ECC) when it
  // overlaps the last blended keyframe less than this, or was not simply followed; the others
  // only link and place (sidecar `blended: false`), and are taken only when frames were followed
  // since the last keyframe (video; not stills at 80 % overlap, where every other frame would be
  // one). The patch image needs no more than this; the adjustment gains from every keyframe.
  // 1 = every keyframe is blended.
  double blend_overlap = 0.75;
  // A keyframe is described (SIFT: stored for the global map's appearance links and loop
  // closures, matched for the patch's loop links and recovery) when it overlaps the patch's last
  // described keyframe less than this, or was not simply followed (recovered, doubtful, first or
  // last of its patch); the others are linked by their tracks, their ground described by their
  // neighbours. 1 = every keyframe (the default). 0.5 on stills at 70 % overlap: every other
  // keyframe, 15-25 % more frames a second for 7-25 % more error per patch (half the links of
  // the patch adjustment are SIFT's); on video twice the error (bench/RESULTS.md).
  double describe_overlap = 1.0;
  // Stills: keyframes taken one after another, no frame followed between them, that overlap less
  // than keyframe_overlap (stills at 70-80 % overlap; video only where it moves that fast). Each
  // is a keyframe, adjusted with the others.
  // - the points each hands on to the next (600: more tracks link it to the frames around it);
  // - described only when it overlaps the last described keyframe less than
  //   still_describe_overlap (1, the default: every still; 0.5: every other one at 70 % overlap,
  //   the others linked by their tracks, their ground described by their neighbours). A still
  //   over a keyframe of the lane before is described all the same (its loop links);
  // - blended only when it overlaps the last blended keyframe less than still_blend_overlap
  //   (0.5, the default: every other one at 70 % overlap, the others in the patch image through
  //   their neighbours). One whose neighbours leave part of its ground out is blended after all
  //   (a lane's last still). A still not blended is described as any (SIFT's doubled first
  //   octave: the global map's links), is not ECC-refined or filtered, and counts as blended for
  //   the next frame's keyframe rule. 1292 x 964 stills 14 % less CPU, 800 x 600 0-10 %; per
  //   patch error 3 % less, global 1 % more over 41 surveys (bench/RESULTS.md, session 45).
  // With 600, 0.5, 0.5 on the spread's stills: 800 x 600 at 70 % overlap 25.6 -> 34.6 frames/s,
  // 1292 x 964 20.3 -> 26.5, per-patch error lower on 9 of 13 kinds (0.32 -> 0.18 px) and on 40
  // of 48 other draws. But the global map after `align` is much worse: 0.40 -> 0.89 px on 984
  // stills (the undescribed ones give it no links), which is why still_describe_overlap stays 1
  // (bench/RESULTS.md, session 29). 600 points alone (every still described) are truer, for
  // CPU: over 20 surveys 0.88 of the error within each patch and 0.97 after `align`, 5-21 % more
  // CPU (tracking 7 -> 13 ms a still at 800 x 600); not the default while the stills are under
  // their frames/s goal (bench/RESULTS.md, session 51).
  int still_track_points = 300;
  double still_describe_overlap = 1.0;
  double still_blend_overlap = 0.5;
  // Features found ahead, by the threads that prepare frames, while the recent frames all needed
  // theirs and some needed them on the engine's own thread (recovery: stills that turn more
  // than following foresees). They are the features the engine would find itself, used only
  // when nothing that shapes them (the overlay mask, a keyframe's coarse or followed
  // description) changed meanwhile: the same map, with SIFT off the engine's path (random-walk
  // stills: the engine's thread was busy 79 % of the run; bench/RESULTS.md, session 39).
  bool features_ahead = true;
  std::string features = "sift";  // sift | orb | akaze
  int max_features = 1000;
  // Features of a keyframe that frames were followed into before it (video): its links to the
  // keyframes around it come from the points followed, SIFT's only from loop closures and
  // recovery, where fewer and stronger features do as well (nine MPEG-4 surveys: 0.58 against
  // 0.64 px per patch at 400, 0.59 at 600; bench/RESULTS.md). Keyframes on stills keep
  // max_features: there fewer cost accuracy.
  int followed_max_features = 400;
  double detect_scale = 0;        // 0 = by frame size (about detect_pixels)
  double detect_pixels = 0.16e6;
  // SIFT's first octave at twice the detection image's size (OpenCV's way): the finest, best-placed
  // features. false: found on the detection image halved, half the time, ~25 % more error.
  bool sift_upsample = true;
  double ratio = 0.8;
  bool cross_check = true;
  bool fundamental = true;        // the F-RANSAC / bilateral epipolar stage
  double epipolar_threshold = 1.5;
  double homography_threshold = 3.0;
  int min_inliers = 25;
  // 3. Consistency: the Kalman gate arbitrates between candidate registrations; a frame that
  // fails against the previous one is tried against the patch's other frames and its image, and
  // rejected frames get a second chance against later ones.
  bool kalman = true;
  bool recover = true;
  // 3b. Each frame's placement fitted against every patch frame it overlaps (not only the
  // previous one), so that error does not accumulate along a lane.
  bool patch_fit = true;
  // 3c. When a patch closes, its frames are adjusted together as cameras over the seafloor plane
  // (Ceres), so that the patch does not bend along a lane, and it is blended from those
  // placements. Its keyframes (filtered images and features) are kept in memory until it is
  // written, at most patch_frames_mb (a patch closes when the next keyframe would pass it, as at
  // the pixel budget). The engine's peak memory is bounded by it: the open patch's keyframes and
  // those of at most two closed patches (one written, one waiting), besides the working canvas
  // (4 bytes a pixel of the budget), one band of the patch being written and a few frames in
  // flight; ~140 MB of libraries on top. See the README for the figures.
  bool adjust_patches = true;
  // Without a calibration file the focal length is only assumed (fov_deg). The adjustment then
  // estimates it with the poses, within a factor of 3 of the assumed one: where the camera's roll
  // and pitch change between frames it is observable, and a wrong one bends the patch (90 degrees
  // across taken for 70, 3 degrees of jitter: 27 px per patch against 0.24; bench/RESULTS.md,
  // session 21); where they do not, it stays about where it starts, which then does no harm. A
  // calibration file's focal length is held, unless it was only assumed (below).
  bool estimate_focal = true;
  // The adjustment's last solve discounts the pairs a link holds beyond this many pixels by a
  // Cauchy loss (0 = the Huber loss from a pixel alone, as engines before session 41): the
  // pairs that agree with each other place the frames (13 % less error within each patch over
  // 46 surveys; bench/RESULTS.md, session 41).
  double patch_robust_loss_px = 0.5;
  // Whether the calibration file's focal length was measured (held) or only assumed, as in the
  // file --calibration auto writes (0.9 x the width, where its radial distortion is found from):
  // that one is where the adjustment starts, as the field of view is without a file.
  bool calibration_focal_measured = true;
  double patch_frames_mb = 128;
  // 4. ECC
  bool ecc = true;
  double ecc_scale = 0.25;
  std::string ecc_motion = "translation";  // translation | euclidean | affine | homography
  // 5. Blending: Gaussian sigma as a fraction of the frame (0.2, 0.1, 0.01), 0 = plain average
  double feather_sigma = 0.2;
  // Colour, before blending: the survey's lighting (vignetting, the lights' cone) divided out,
  // each frame's exposure matched to its neighbours', the water's colour cast balanced. The
  // survey-wide estimates are kept in <store>/lighting.json.
  bool flat_field = true;
  bool exposure = true;
  bool water_colour = true;
  // 6. Memory management. A patch's budget is at least twice a frame's pixels (unless
  // patch_memory_mb bounds it): under that (5 Mpx for 3840 x 2160 frames, 8.3 Mpx each) every
  // keyframe would close a patch, leaving the patch adjustment nothing to adjust.
  double patch_megapixels = 5.0;
  double patch_memory_mb = 0;     // if > 0, also bounds the patch canvas (16 bytes a pixel)
  int max_lost_frames = 3;        // consecutive failures that close a patch
  // Live: the open patch is closed (written, and the next one linked to it) after this many
  // frames, so that a crash or power cut loses at most these; 0 = only by the pixel budget.
  int checkpoint_frames = 0;
  TiffWriteOptions tiff = PatchWriteOptions();  // patch images

  // Patches are intermediate, and the writer must keep up with the camera: JPEG at quality 85
  // with the alpha as a 1-bit mask. On the paper's patches it is the size of WebP at quality 90
  // (libwebp effort 0, the default before), 0.5 dB closer to the blend at full resolution, and
  // 5 times faster to encode (bench/RESULTS.md, session 11).
  static TiffWriteOptions PatchWriteOptions() {
    TiffWriteOptions t;
    t.compression = Compression::kJpegMask;
    t.quality = 85;
    t.webp_method = 0;  // for --compression webp
    return t;
  }

  bool IsValid(std::string* error) const;
  // The patch budget in pixels, for frames of `frame` (empty: patch_megapixels and
  // patch_memory_mb alone).
  long long PixelBudget(cv::Size frame = cv::Size()) const;
};

struct FrameReport {
  int index = 0;
  std::string source;
  std::string status;   // "stitched" or "rejected"
  std::string reason;   // why rejected
  bool keyframe = false;  // stitched as a keyframe (blended), not only placed
  std::string note;       // e.g. "duplicate of frame 5" (placed, not blended)
  int patch_id = 0;
  bool started_patch = false;
  // Placed relative to the frames before it: in the open patch, or opening the next one linked
  // to it (the pixel budget). False for a rejected frame and for a patch begun after the thread
  // broke: the ground between it and the frame before may be missing from the map.
  bool continues = false;
  int matches = 0, inliers = 0;
  double bilateral_error = 0;  // mean bilateral epipolar error of the survivors, pixels
  double ecc = 0;        // ECC correlation (0 when not run)
  double ecc_shift = 0;  // how far ECC moved the frame's corners, pixels
  double seconds = 0;
};

struct MosaicSummary {
  int frames = 0, stitched = 0, rejected = 0, patches = 0;
  int keyframes = 0;  // of the stitched: adjusted together (the others are placed between them)
  int blended = 0;    // of the keyframes: blended into the patch image
  int described = 0;  // of the keyframes: their features found and stored
  int recovered = 0;  // of the stitched: rejected at first, registered against a later frame
  int adjusted = 0, unadjusted = 0;  // patches whose placements the adjustment replaced, or not
  // The patches the adjustment did not fit, and why (their online placements kept).
  std::vector<std::pair<int, std::string>> unadjusted_why;
  // The frames rejected for good (not those placed on a second chance), in the order of the input,
  // each with its reason: `rejected` counts them. Also in their patches' sidecars, except when no
  // patch was written at all (every frame rejected: open water, black, unreadable).
  std::vector<RejectedFrame> rejected_frames;
  // Of those, the patches whose frames fit no flat ground seen through a pinhole camera (solved,
  // but their transfer error stayed above the bound): a lens that distorts, or ground far from
  // flat. And those of fewer than three frames, which have nothing to adjust.
  std::vector<int> misfit_patches, trivial_patches;
  double seconds = 0;
  double cpu_seconds = 0;  // the process's CPU time (user + system, every thread) during the run
  double peak_rss_mb = 0;
  // Time spent in each stage, summed over frames (seconds): where the time goes.
  std::vector<std::pair<std::string, double>> stage_seconds;
  std::vector<std::string> keyframe_stages;  // the stages that run for keyframes only
  // CPU time no stage names (OpenCV's helper threads, hand-overs between threads): cpu_seconds
  // less the stages, at least 0.
  double RestCpuSeconds() const;
  std::string calibration_note;  // what --calibration auto found, when used
  std::string mask_note;         // what --mask auto found, when used
  // Frames were followed (Lucas-Kanade) at this fraction of their size (MosaickerOptions::
  // track_pixels, track_halve); 0 before the first frame.
  double track_scale = 0;
  int frames_skipped = 0;        // live: frames that arrived and were not mapped (busy, or left at a stop)
  int coverage_lost = 0;         // live: of those skips, the ones after which the thread broke
  int frames_shedding = 0;       // live: frames mapped while load was shed (LiveOptions::shed_describe_overlap)
  int features_ahead = 0;        // frames whose features were found ahead (MosaickerOptions::features_ahead) and used
  std::string preview_problem;   // live: why the open patch's preview could not be written
  // MosaicInput stopped (its `stop` set) before the input ended: the frames after `frames` were
  // not mapped; the open patch was written as at the end of the input.
  bool stopped = false;
};

// Live input (MosaicLive): a folder that grows, or a stream (camera device, rtsp://, udp://, a
// GStreamer pipeline). See src/input/live_source.h.
struct LiveOptions {
  double idle_timeout_s = 0;  // 0: wait for frames until stopped
  // How often a folder is listed: frames that arrive are seen at once where the file system
  // reports them (inotify: written and closed, or renamed into the folder); the listing finds
  // the others (network file systems), a file counting once its size held over a listing.
  double poll_s = 0.1;
  // The backlog: frames received and not yet mapped (those being prepared included) are at most
  // this many; beyond it the oldest waiting frames are skipped, never the newest. It absorbs the
  // engine's bursts (a patch closing, a lane join): stills overlap so that a frame skipped breaks
  // the chain, and with 3 an engine as fast as its feed on average fell behind at each burst and
  // lost a third to half of a 10 frames/s feed (bench/RESULTS.md, session 12). 12 frames: 1.2 s
  // at 10 frames/s, 0.4 s at 30, reached only while the engine is behind.
  int max_waiting = 12;
  // Load shedding (Mosaicker::ShedLoad): while the backlog is at least half its bound, and until
  // it is down to a quarter, keyframes are described (SIFT) only when they overlap the last
  // described one less than this (MosaickerOptions::describe_overlap otherwise). Frames are then
  // mapped faster (every other keyframe described on 70 % stills: 15-27 % more frames a second,
  // 7-25 % more error per patch, bench/RESULTS.md) rather than skipped, which on stills breaks the
  // chain of frames; each break costs a search that puts the engine further behind.
  // 1: never shed.
  double shed_describe_overlap = 0.5;
  // How often the open patch is written for the page (STORE/live/preview.json); 0: never.
  double preview_s = 2.0;
  const std::atomic<bool>* stop = nullptr;  // set (e.g. by SIGINT) to end the run cleanly

  bool IsValid(std::string* error) const;
};

// Where a live run stands (STORE/live/status.json, GET /api/status).
struct LiveStatus {
  bool running = false;
  long long frames_received = 0, frames_registered = 0, frames_rejected = 0, frames_skipped = 0;
  // Frames skipped where the frame taken next did not join the one before it (rejected, or it
  // opened a patch of its own): ground the map may have missed.
  long long coverage_lost = 0;
  long long frames_incomplete = 0;  // files cut short and never finished (taken as they are)
  int backlog_max = 0;    // the most frames received and not yet mapped at once
  int backlog_bound = 0;  // the most there may be (LiveOptions::max_waiting)
  // Frames mapped while the engine shed load to keep up (LiveOptions::shed_describe_overlap),
  // and whether it sheds now.
  long long frames_shedding = 0;
  bool shedding = false;
  int patches = 0;             // written by this run
  int open_patch = 0;          // id of the patch being built (0: none)
  double last_frame_time = 0;  // Unix seconds of the newest frame received
  double latency_ms_p50 = 0, latency_ms_p95 = 0;  // arrival to integration, last 600 frames
  double started = 0, updated = 0;
};

// The patch being built, as the engine sees it (Mosaicker::Preview): what a live page shows
// before the patch closes. Coordinates are the open patch's own (its first frame's pixel grid,
// the coordinates its frames have until it closes).
struct LivePreview {
  int patch_id = 0;   // 0: no patch is open
  cv::Mat image;      // the working canvas blended, BGRA 8-bit (alpha 0 where nothing is)
  cv::Matx33d patch_to_image = cv::Matx33d::eye();  // patch coordinates -> image pixels
  std::vector<cv::Point2d> track;                    // frame centres, patch coordinates
  std::vector<std::string> track_frames;             // those frames' names (sources)
  cv::Size frame_size;
  std::vector<cv::Point2d> footprint;                // the last frame placed: its 4 corners
  int frames = 0;                                    // placed in the patch so far
  int last_index = -1;                               // the frame placed last: its index and name
  std::string last_source;
  // When the patch continues the one before (the pixel budget closed it): its id, and this
  // patch's coordinates -> that patch's first frame's grid (before its adjustment).
  int previous_patch = 0;
  cv::Matx33d to_previous_first = cv::Matx33d::eye();
};

class Mosaicker {
 public:
  // Throws Error when the options are invalid or the calibration cannot be read.
  Mosaicker(Store store, const MosaickerOptions& options);
  ~Mosaicker();
  Mosaicker(const Mosaicker&) = delete;
  Mosaicker& operator=(const Mosaicker&) = delete;

  // One frame (BGR 8-bit; empty = unreadable, recorded with `error` as the reason).
  FrameReport Push(const cv::Mat& frame, const std::string& source, const std::string& error = "");
  // Push in parts, for pipelining. Prepare (undistortion, the tracking image and its pyramid) is
  // thread-safe: several frames may be prepared at once, on any threads. Integrate (tracking,
  // registration, checks, refinement, blending) takes the frames in order, from one thread at a
  // time; keyframes' filtering and features run on the engine's own workers meanwhile.
  std::shared_ptr<PreparedFrame> Prepare(const cv::Mat& frame, const std::string& source,
                                         const std::string& error = "");
  FrameReport Integrate(const std::shared_ptr<PreparedFrame>& frame);
  // Closes and writes the last patch, waits for the writer. Returns the totals.
  MosaicSummary Finish();
  // The open patch at `scale` of full resolution (at most the working canvas's half), reduced
  // further so the image holds at most `max_megapixels`. From the thread that calls Integrate,
  // between frames.
  // Without `image`, everything but the image (cheap: for the track between images).
  LivePreview Preview(double scale = 0.5, double max_megapixels = 2.0, bool image = true) const;
  // How far the last frame placed moved from the one placed before it, as a fraction of the
  // frame's extent along that motion (0 to 1+; 0 when fewer than two frames of the open patch):
  // a live source's measure of how many frames it may skip without losing ground. Same thread
  // as Integrate.
  double LastStepFraction() const;
  // Load shedding, for a live run behind its feed: while on, keyframes integrated are described
  // at `describe_overlap` when that is below MosaickerOptions::describe_overlap (SIFT is most of
  // a still keyframe's cost). Off: as the options say. (Leaving out the search of the patch image
  // for frames that cannot be followed as well lost more frames than it saved, session 12.) While
  // on, recovery's last try (the frame and the last keyframe described densely) is left out.
  // Same thread as Integrate. Throws Error when `describe_overlap` is outside (0, 1].
  void ShedLoad(bool on, double describe_overlap = 0.5);
  // An overlay mask found after the run began (MosaickerOptions::mask's image; a live run's
  // overlay search goes on past a descent): frames prepared from now on leave it out of tracking
  // and features, and keyframes integrated from now on out of blending. Any thread. Throws Error
  // naming the file when it cannot be read.
  void UseMask(const std::string& path);
  // Called (from the writer thread) after each patch is committed to the store.
  void OnPatch(std::function<void(const PatchSidecar&)> callback);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Maps frames as they arrive (LiveOptions) into the store until the source ends or is stopped;
// the open patch is then written as at the end of a survey. `on_status` is called at least twice a
// second while frames come, at each patch written, and at the end.
MosaicSummary MosaicLive(const std::string& input, Store store, const MosaickerOptions& options,
                         const LiveOptions& live, const std::function<void(const LiveStatus&)>& on_status = nullptr,
                         const std::function<void(const FrameReport&, int total)>& on_frame = nullptr);

// Throws Error naming `input` when it is no folder of frames, list of frames or video that opens:
// checked before a store is made for it, so that a mistyped path leaves no empty store behind.
void CheckMosaicInput(const std::string& input);

// Reads INPUT (folder, list, video) and mosaics it into the store; `on_frame` sees every frame.
// When `stop` is set (e.g. by SIGINT) no further frame is read: the frames read are mapped, the
// open patch is written as at the end of the input, and the summary says `stopped`. `on_note`
// hears what the run does before its first frame is mapped when that takes long (the overlay
// search reading on past a descent).
MosaicSummary MosaicInput(const std::string& input, Store store, const MosaickerOptions& options,
                          const std::function<void(const FrameReport&, int total)>& on_frame = nullptr,
                          const std::atomic<bool>* stop = nullptr,
                          const std::function<void(const std::string&)>& on_note = nullptr);

}  // namespace rolamos
