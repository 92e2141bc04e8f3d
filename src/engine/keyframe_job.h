// What a keyframe needs beyond its placement, made off the engine's thread while the frames after
// it are followed: the paper's spatio-temporal filter (the keyframe averaged with the frame before
// it where the two agree, when that frame was not blended itself, then the bilateral filter), its
// SIFT features (stored for the global map, used for recovery), and its links with the older
// keyframes of the patch under it (an earlier lane: loop closures for the adjustment), and the
// frames followed since the keyframe before, registered against this one too.
#pragma once

#include <algorithm>
#include <functional>
#include <future>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "engine/prepared_frame.h"
#include "engine/preprocess.h"
#include "engine/egomotion.h"
#include "engine/registration.h"
#include "engine/tracker.h"

namespace rolamos {

// A frame followed from the keyframe before this one (KeyframeJob::followed_from; not a keyframe
// itself): this keyframe's points are followed back into it.
struct FollowedFrame {
  int index = 0;
  std::shared_ptr<const TrackFrame> track;
  cv::Matx33d to_before;  // its pixels -> the keyframe's it was followed from
  int inliers = 0;        // of that registration
};

// The frames followed since the last keyframe, for the next keyframe to follow its points back
// into. Each holds its pyramid until then, and a vehicle that holds still or creeps makes no
// keyframe for as long as it does: at most `capacity` are kept, spread evenly over the frames
// followed (when full, every other one goes, and from then on only every other one is taken).
// The frames not kept are placed from the keyframe before them alone.
class FollowedSample {
 public:
  static constexpr size_t kDefaultCapacity = 16;
  explicit FollowedSample(size_t capacity = kDefaultCapacity) : capacity_(std::max<size_t>(capacity, 2)) {}
  void Add(FollowedFrame f);
  // The frames kept, leaving the sample empty for the next keyframe.
  std::vector<FollowedFrame> Take();
  void Clear() { Take(); }
  size_t size() const { return kept_.size(); }

 private:
  size_t capacity_;
  long long seen_ = 0;    // frames offered since the last Take
  long long stride_ = 1;  // every stride-th of them is kept
  std::vector<FollowedFrame> kept_;
};

// A frame followed between two keyframes and registered against both: it is placed where the two
// put it, each weighted by its inliers (a followed frame's error goes with its support).
struct FollowedBetween {
  int index = 0;
  int before = 0, after = 0;        // the keyframes
  cv::Matx33d to_before, to_after;  // its pixels -> theirs
  double weight_before = 0.5;
};

struct KeyframeProducts {
  cv::Mat image;  // filtered, BGR 8-bit: what the patch blends (empty: not blended)
  std::shared_ptr<const Features> features;
  std::vector<FrameLink> loop_links;  // a = this keyframe
  std::vector<FollowedBetween> between;  // the frames followed before it, registered against it
  double filter_seconds = 0, link_seconds = 0, follow_seconds = 0;  // what each part took
};
using KeyframeFuture = std::shared_future<KeyframeProducts>;

// An older keyframe of the patch that the new one lies over.
struct OlderKeyframe {
  int index = 0;
  cv::Matx33d to_patch;
  KeyframeFuture products;
  bool loop = false;  // of an earlier lane (not among the recent keyframes): a loop closure
};

struct KeyframeJob {
  int index = 0;
  std::shared_ptr<PreparedFrame> frame;
  // The frame before it when that one was not blended (the temporal filter's other term), and
  // the homography from this frame's pixels to its pixels.
  std::shared_ptr<PreparedFrame> before;
  cv::Matx33d to_before = cv::Matx33d::eye();
  cv::Matx33d to_patch = cv::Matx33d::eye();
  std::vector<OlderKeyframe> older;
  // Blended into the patch image: filtered, its image kept. Otherwise it links and places only
  // (no image in the products), and its frame stays as it is: the next keyframe may average it in.
  bool blend = true;
  // Its pyramid and the points it hands on, followed back into `followed` (a copy of the
  // pyramid's pointer: the engine drops the frame's own while the job may run).
  std::shared_ptr<const TrackFrame> track;
  std::vector<cv::Point2f> points;
  std::shared_ptr<SharedWindows> windows;  // around `points`: the engine's, when it follows from them
  // The frames followed from the keyframe before (index `followed_from`, placed at
  // `followed_from_to_patch`).
  std::vector<FollowedFrame> followed;
  int followed_from = 0;
  cv::Matx33d followed_from_to_patch = cv::Matx33d::eye();
};

struct KeyframeTools {
  const Preprocessor* pre = nullptr;
  bool bilateral = true, temporal = true;
  // The frame's SIFT features (computed once per frame, whoever asks first).
  std::function<std::shared_ptr<const Features>(PreparedFrame&)> features;
  PatchFitOptions fit;
  const FrameTracker* tracker = nullptr;  // for `followed`
  cv::Matx33d K = cv::Matx33d::eye();
  EgomotionOptions ego;
  SupportOptions support;
};

// The keyframe's points followed back into each of the frames followed before it, and each
// registered by the egomotion stage (F-RANSAC, bilateral check, homography); a frame whose
// registration is not strong is left out.
std::vector<FollowedBetween> FollowBack(const KeyframeJob& job, const KeyframeTools& tools);

// Releases a blended frame's unfiltered image when done: the engine must not read it afterwards.
KeyframeProducts RunKeyframeJob(const KeyframeJob& job, const KeyframeTools& tools);

}  // namespace rolamos
