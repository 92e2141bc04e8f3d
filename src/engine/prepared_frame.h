// A frame between the two halves of the engine: what Mosaicker::Prepare made of it (on any
// thread) and what Mosaicker::Integrate takes, in order.
#pragma once

#include <memory>
#include <mutex>
#include <string>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "engine/tracker.h"

namespace rolamos {

struct PreparedFrame {
  std::string source, error;
  cv::Size size;
  cv::Mat image;  // BGR 8-bit, undistorted, not yet smoothed (only blended frames are)
  // Released by the engine's thread once the frame is no longer followed from or into (a
  // keyframe behind the recent ones); the keyframe job that may still hold the frame never reads it.
  std::shared_ptr<const TrackFrame> track;
  // SIFT features: found when first needed (keyframes, recovery), once, by whoever asks first.
  std::once_flag features_once;
  std::shared_ptr<const Features> features;
  // Found ahead by the thread that prepared the frame (MosaickerOptions::features_ahead), with
  // the extractor and the generation of the overlay mask they were found with: taken by the first
  // to ask for `features` when they are what it would find (the frame's extractor, the same
  // mask), else dropped.
  std::shared_ptr<const Features> ahead;
  const FeatureExtractor* ahead_by = nullptr;
  long ahead_mask = -1;
  // Described three times as densely, when recovery's last try needed it (engine thread only):
  // kept, for the frame may be tried again as the keyframe the next one is matched with.
  std::shared_ptr<const Features> dense_features;
  // Set before they are found: a keyframe that links but is not blended is described by SIFT
  // without its doubled first octave (half the time; its links are held by its neighbours').
  bool coarse_features = false;
  // Set before they are found: frames were followed into this keyframe before it (video), so
  // it is described by MosaickerOptions::followed_max_features.
  bool followed_features = false;
  // Camera frames skipped just before this one (a live source that could not keep up; 0 in a
  // survey): the motion model predicts over them. Set before Integrate.
  int skipped_before = 0;
  // Its number among the camera's frames (skipped ones counted), set by Integrate.
  long camera_frame = 0;
};

}  // namespace rolamos
