// Where the overlay search (`mosaic --mask auto`) looks: the survey's first frames, and, when
// those cannot tell (the seafloor hardly moves under them), the frames after them. An ROV's video
// starts with its descent: minutes of open water that hold nothing but the burned-in overlay, so
// that the first frames were taken for a camera that does not move, no mask was made, and the
// overlay held registrations still once the seafloor came (a patch 678 px off).
#pragma once

#include <atomic>
#include <deque>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/preprocess.h"
#include "engine/static_mask.h"
#include "rolamos/mosaicker.hpp"

namespace rolamos {

// The overlay in `raw` (frames as the input gave them; undistorted here as the engine will see
// them, empty ones skipped).
StaticMask FindOverlay(const std::vector<cv::Mat>& raw, const MosaickerOptions& options);

struct OverlaySearchOptions {
  int step = 8;             // frames between two looks at the latest ones
  // Frames read at most: 30 minutes at 30 frames/s, an ROV's descent to 1,000 m (two minutes,
  // as before, left deeper dives' overlays unfound).
  int max_frames = 54000;
  // Called with the frames read so far, every `progress_every` (a long search is not silent).
  std::function<void(int read)> progress;
  int progress_every = 240;
};

// The frames after the first ones, looked at window by window: each frame goes in as it is read;
// every `step` frames, once a window of the overlay search's frame count is full, the window is
// looked at. One preprocessor for the whole search (its undistortion maps made once), and each
// frame undistorted once, as it enters, not again in each window it is in.
class OverlayWindows {
 public:
  // `skip`: the frames the first look had (named in the notes).
  OverlayWindows(const MosaickerOptions& options, int skip, const OverlaySearchOptions& search = {});
  // Frame `index` (as the input gave it) into the window. True when a window was looked at:
  // result() is its finding (conclusive() when it tells).
  bool Add(int index, const cv::Mat& image);
  const StaticMask& result() const { return result_; }
  bool conclusive() const { return result_.conclusive; }
  // Frames added so far; the search is over at the options' max_frames.
  int seen() const { return seen_; }
  bool exhausted() const { return seen_ >= search_.max_frames; }
  // The last finding's note, with how many frames were read (by default those added).
  std::string FinalNote(int read = -1) const;

 private:
  StaticMaskOptions mask_options_;
  OverlaySearchOptions search_;
  int skip_;
  Preprocessor pre_;
  std::deque<std::pair<int, cv::Mat>> latest_;  // grey (the search looks at nothing else)
  StaticMask result_;
  int seen_ = 0, since_ = 0;
};

// The search over a folder, list or video read again from its start: frames after the first
// `skip` are looked at in windows of the overlay search's frame count, every `step` frames, until
// a window tells. Returns the first such window's result, its note naming the frames; otherwise
// the last window's, inconclusive. Reads no further once `stop` is set.
StaticMask SearchOverlayFurther(const std::string& input, int skip, const MosaickerOptions& options,
                                const OverlaySearchOptions& search = {},
                                const std::atomic<bool>* stop = nullptr);

}  // namespace rolamos
