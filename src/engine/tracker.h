// Stage 2, between keyframes: points followed from frame to frame with pyramidal Lucas-Kanade
// (the "direct" family the paper's section 3.2 sets beside feature matching, suited to the large
// overlap of consecutive video frames). Every frame is followed from the current keyframe, not
// from the frame before, so tracking error does not add up between keyframes; each point is
// checked forward and backward, and corners are topped up where the points thin out. SIFT then
// runs only where it is needed (keyframes, recovery), not on every frame.
#pragma once

#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct TrackerOptions {
  // Frames are followed at a reduced size: halved until the tracking image holds at most this
  // many pixels (800 x 600 at full size; 1024 x 768 to 1920 x 1080 at half). The pyramid costs
  // in proportion to it, a point's flow does not.
  double track_pixels = 0.6e6;
  // Halved at least once all the same, unless the frame holds less than 0.4 of track_pixels
  // (480 x 360): for frames from a video codec. Its blocks stay where the pixel grid is and its
  // fine detail is gone; a window over twice the ground follows such frames better, and for a
  // quarter of the pyramid (800 x 600 MPEG-4: 0.43 against 0.58 px per patch, 67 against 48
  // frames/s). Stills lose by it (800 x 600 and 640 x 480: 0.71 against 1.23 px on strong
  // noise and marine snow, 0.30 against 0.35 with lanes apart; bench/RESULTS.md).
  bool halve_once = false;
  // Such frames are then halved until they hold at most this many pixels (with track_pixels, the
  // smaller): 1292 x 964 and 1920 x 1080 at a quarter, 1280 x 720 and smaller at half. What a
  // codec left of large frames is followed over four times the ground, in a sixteenth of the
  // pyramid; the engine hands on twice the points there (MosaickerOptions::track_points). MPEG-4
  // at 1292 x 964: 0.26 against 0.32 px per patch, dark under the lights' cone 0.63 against 0.99,
  // 1920 x 1080 0.12 against 0.16, at about the speed of half size (bench/RESULTS.md, session 17).
  double codec_pixels = 0.25e6;
  int max_points = 300;     // points a keyframe hands on (PointsFor)
  // Lucas-Kanade's window, tracking pixels, for frames followed at full size
  // (MosaickerOptions::track_window). 31 averages a point's place over twice the pixels of 21
  // (640 x 480 stills with noise and the lights' cone 1.1-2.0 -> 0.65-1.2 px per patch, 800 x
  // 600 stills 0.32 -> 0.20; bench/RESULTS.md, sessions 49-50).
  int window = 31;
  // Frames followed halved: stills larger than track_pixels, and a codec's frames (halve_once).
  // 21 there spans 42 frame pixels already. 31 placed such stills no better (1024 x 768 turning
  // stills 10-15 % worse) for ~4 % more CPU, and 800 x 600 MPEG-4 worse on four of seven
  // surveys (random walk 0.34 -> 0.44 px, the lights' cone 1.00 -> 1.15) for 3-14 % more CPU:
  // they keep 21 whatever `window` is.
  int halved_window = 21;
  // The window for a codec's frames followed at a quarter or less (PointsFor's frames): 21 there
  // spans 84 frame pixels, twice the ground of the window at half size. At 13 the quarter-size
  // video surveys are placed as well or better (1292 x 964 random walk 0.30 -> 0.27 px, H.264
  // 0.85 -> 0.77, five others within 0.01) and followed 4-16 % faster (bench/RESULTS.md,
  // session 18).
  int quarter_window = 13;
  int levels = 3;           // pyramid levels above the tracking image
  double max_fb_px = 0.7;   // forward-backward disagreement allowed, tracking pixels
  // Lucas-Kanade stops at a level after this many steps, or once a step moves less than
  // `min_step_px` (tracking pixels). 10 steps to 0.03 px cost ~12 % less than 20 to 0.01 with
  // the same per-patch error (nine MPEG-4 surveys: 0.63 against 0.66 px, bench/RESULTS.md).
  int max_iterations = 10;
  double min_step_px = 0.03;
  // Contrast normalised before following: each pixel's difference from the mean around it
  // (a Gaussian of this sigma, tracking pixels), divided by the standard deviation around it.
  // Dark and hazy seafloor has texture only relative to itself; a frame darker than the one
  // before, the lights' cone and vignetting (smooth, multiplicative) look alike after it, and
  // the same ground gives the same values in every frame (a global or CLAHE-like stretch would
  // not: its mapping depends on what else is in the frame). 0 = off.
  double normalize_sigma = 8.0;
  // Lucas-Kanade's windows are square and do not turn: a frame turned more than this (degrees)
  // from the one it is followed from is followed in a copy of it warped back by the guess, and
  // the points mapped forward again. In turns the frames a few steps from their keyframe were
  // otherwise placed up to 1 px off, a follow 12 degrees round keeping 117 of 268 points (spiral
  // 0.17 -> 0.13 px per patch, MPEG-4 video at 800 x 600 0.79 -> 0.67; bench/RESULTS.md). It
  // costs a warp and a pyramid per such follow. 0 = never.
  double turn_deg = 2.0;
  // CoarseTurn's search: turns of up to this many degrees each way, in steps of
  // `turn_search_step_deg` (then half a step each side of the best). 0 = no turn searched (the
  // engine's default: MosaickerOptions::track_turn_search_deg).
  double turn_search_deg = 0.0;
  double turn_search_step_deg = 12.0;
  // A follow that may give up (Follow's `may_give_up`: a start, where another may hold) follows
  // every fourth point first, and the others only when at least this share of those was. Starts
  // that fail keep 0-22 % of their points (median 5 %; 80 % of them under 8 %), those that hold
  // at least 12 % (the 28 kinds of bench/run_engine_spread.py, ~9,400 follows): by the sample's
  // chance, less than one of those ~6,900 holding follows would be given up (bench/RESULTS.md,
  // session 40). 0 = the whole follow always.
  double give_up_below = 0.08;
  // Shi-Tomasi, relative to the frame's 30th strongest corner (a few bright specks, marine snow,
  // do not set the scale for the rest).
  double corner_quality = 0.01;

  bool IsValid(std::string* error) const;
  double ScaleFor(cv::Size frame) const;
  // The points a keyframe of `frame`'s size hands on: max_points, twice that for a codec's frames
  // followed at a quarter or less (their pyramid is a quarter of the half-size one, a point costs
  // what it did; bench/RESULTS.md, session 17).
  int PointsFor(cv::Size frame) const;
  // The Lucas-Kanade window (tracking pixels) for frames of `frame`'s size: window at full size,
  // halved_window for frames followed halved, or quarter_window for the frames PointsFor doubles.
  int WindowFor(cv::Size frame) const;
  // A codec's frames followed at a quarter of their size or less: the frames both rules above
  // are for.
  bool CodecAtAQuarter(cv::Size frame) const;
};

// A frame as the tracker sees it: its grey image at the tracking scale and that image's pyramid
// (with derivatives), made once, on any thread.
struct TrackFrame {
  cv::Size size;       // the frame's full size
  double scale = 1.0;  // tracking image / frame
  std::vector<cv::Mat> pyramid;
  cv::Mat usable;      // tracking scale, 0 where a static overlay is (empty: everywhere usable)
};

// Points followed from one frame into another (full-resolution pixels).
struct TrackFlow {
  std::vector<cv::Point2f> to;
  std::vector<uchar> ok;  // followed both ways and back to where it started
  int followed = 0;
  // Given up after a failed sample (Follow's `may_give_up`): only the sample's points were followed.
  bool cut_short = false;
  // The points followed (`ok`): where they landed, and where they started (`points` as given to
  // Follow); `which` (optional), their indices in `points`.
  void Kept(const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* landed,
            std::vector<cv::Point2f>* started, std::vector<size_t>* which = nullptr) const;
};

class LucasKanadeTemplates;

// The windows of a keyframe around the points it hands on (LucasKanadeTemplates), made by the
// first follow from those points, on whichever thread comes first: the engine's, following the
// next frame, or the keyframe's job's, following the points back into the frames before it.
// Both read the same windows; each made its own before (a fifth of the following on video).
class SharedWindows {
 public:
  // The windows, made by `make` on the first call; a call meanwhile waits for them.
  const LucasKanadeTemplates& Get(const std::function<std::shared_ptr<const LucasKanadeTemplates>()>& make);

 private:
  std::once_flag made_;
  std::shared_ptr<const LucasKanadeTemplates> windows_;
};

class FrameTracker {
 public:
  explicit FrameTracker(const TrackerOptions& options);
  // `bgr` or grey, 8-bit, full resolution; `usable` (optional, frame size, 0 = overlay).
  std::shared_ptr<const TrackFrame> Prepare(const cv::Mat& frame, const cv::Mat& usable = cv::Mat()) const;
  // Up to `count` corners of `frame` (full-resolution pixels), spread over it, away from the
  // points it already has (`existing`). After contrast normalisation sensor noise has corners
  // too: a frame without texture (open water) is told by its points not being followed into
  // the next frame, and by its SIFT responses (features.h).
  std::vector<cv::Point2f> Corners(const TrackFrame& frame, const std::vector<cv::Point2f>& existing,
                                   int count) const;
  // `points` of `from` followed into `to`, starting where `guess` (from -> to pixels) puts them.
  // `windows` (optional) keeps the windows of `from` around `points` for the next follow from
  // the same points: made on the first call, read on the others.
  // `may_give_up`: a sample is followed first, the rest only if enough of it was
  // (TrackerOptions::give_up_below); else the flow is cut short. The points followed are
  // followed as without it (each point is followed on its own).
  TrackFlow Follow(const TrackFrame& from, const TrackFrame& to, const std::vector<cv::Point2f>& points,
                   const cv::Matx33d& guess, SharedWindows* windows = nullptr, bool may_give_up = false) const;
  // A coarse translation from `from` to `to` (full-resolution pixels) by phase correlation of
  // the pyramids' coarsest levels, after `guess`: a start when there is no prediction.
  cv::Matx33d CoarseShift(const TrackFrame& from, const TrackFrame& to, const cv::Matx33d& guess,
                          double* response) const;
  // The same with the frame also turned about its centre (not by `guess`'s turn: by up to
  // turn_search_deg either way), the turn that correlates best: a start for a frame that turned
  // more than anything foresaw (a random walk turns by up to 40 degrees from one still to the
  // next). The correlation is on the coarsest level at least 96 pixels across, where a turned
  // view is still told from a wrong one. Returns `guess` with *response 0 when no turn is
  // searched or the levels are too small.
  cv::Matx33d CoarseTurn(const TrackFrame& from, const TrackFrame& to, const cv::Matx33d& guess,
                         double* response) const;
  const TrackerOptions& options() const { return options_; }

 private:
  TrackerOptions options_;
};

}  // namespace rolamos
