// Where the overlay search (`mosaic --mask auto`) looks: the survey's first frames, and, when
// those cannot tell (the seafloor hardly moves under them), the frames after them. An ROV's video
// starts with its descent: minutes of open water that hold nothing but the burned-in overlay, so
// that the first frames were taken for a camera that does not move, no mask was made, and the
// overlay held registrations still once the seafloor came (a patch 678 px off).
#pragma once

#include <atomic>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/static_mask.h"
#include "rolamos/mosaicker.hpp"

namespace rolamos {

// The overlay in `raw` (frames as the input gave them; undistorted here as the engine will see
// them, empty ones skipped).
StaticMask FindOverlay(const std::vector<cv::Mat>& raw, const MosaickerOptions& options);

struct OverlaySearchOptions {
  int step = 8;             // frames between two looks at the latest ones
  int max_frames = 3600;    // frames read at most (two minutes at 30 frames/s)
};

// The search over a folder, list or video read again from its start: frames after the first
// `skip` are looked at in windows of the overlay search's frame count, every `step` frames, until
// a window tells. Returns the first such window's result, its note naming the frames; otherwise
// the last window's, inconclusive. Reads no further once `stop` is set.
StaticMask SearchOverlayFurther(const std::string& input, int skip, const MosaickerOptions& options,
                                const OverlaySearchOptions& search = {},
                                const std::atomic<bool>* stop = nullptr);

}  // namespace rolamos
