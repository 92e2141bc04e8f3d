// What a keyframe needs beyond its placement, made off the engine's thread while the frames after
// it are followed: the paper's spatio-temporal filter (the keyframe averaged with the frame before
// it where the two agree, when that frame was not blended itself, then the bilateral filter), its
// SIFT features (stored for the global map, used for recovery), and its links with the older
// keyframes of the patch under it (an earlier lane: loop closures for the adjustment).
#pragma once

#include <functional>
#include <future>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "engine/prepared_frame.h"
#include "engine/preprocess.h"
#include "engine/registration.h"

namespace rolamos {

struct KeyframeProducts {
  cv::Mat image;  // filtered, BGR 8-bit: what the patch blends (empty: not blended)
  std::shared_ptr<const Features> features;
  std::vector<FrameLink> loop_links;  // a = this keyframe
  double filter_seconds = 0, link_seconds = 0;  // what the filter and the loop links took
};
using KeyframeFuture = std::shared_future<KeyframeProducts>;

// An older keyframe of the patch that the new one lies over.
struct OlderKeyframe {
  int index = 0;
  cv::Matx33d to_patch;
  KeyframeFuture products;
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
};

struct KeyframeTools {
  const Preprocessor* pre = nullptr;
  bool bilateral = true, temporal = true;
  // The frame's SIFT features (computed once per frame, whoever asks first).
  std::function<std::shared_ptr<const Features>(PreparedFrame&)> features;
  PatchFitOptions fit;
};

// Releases a blended frame's unfiltered image when done: the engine must not read it afterwards.
KeyframeProducts RunKeyframeJob(const KeyframeJob& job, const KeyframeTools& tools);

}  // namespace rolamos
