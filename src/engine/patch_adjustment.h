// When a patch closes, its frames are placed once more, together: each as a camera pose over the
// seafloor plane (geometry/plane_camera.h), adjusted to every link the engine found between them
// (the frame before, the other patch frames under it). The online placements chain homographies
// and bend along a lane; the adjusted ones do not. The patch image is then blended from the
// adjusted placements, in the plane's coordinates (the first frame's pixel scale and heading).
#pragma once

#include <optional>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "engine/registration.h"
#include "geometry/plane_adjustment.h"

namespace rolamos {

// At most `max_pairs` of a link's matches, spread over frame a (a grid of cells taken in turn):
// enough to pin a pose, few enough for surveys of thousands of frames.
FrameLink Thin(FrameLink link, int max_pairs, cv::Size frame);

struct PatchAdjustmentOptions {
  bool enabled = true;
  // With solver.refine_focal, the focal length is found first with the poses over links thinned
  // to kFocalPairs pairs, then the poses over every pair at that focal length.
  PlaneAdjustmentOptions solver;
  // The poses are solved last under a Cauchy loss from this many pixels (0 = the solver's Huber
  // loss from a pixel alone). After the Huber solve a link's pairs are off by a median of 0.3-0.7
  // px, with a long tail (a codec's blocks, a corner followed onto its neighbour, SIFT's guided
  // matches kept within 3 px), and every pair pulled, up to a pixel in proportion to how far off
  // it was. Under Cauchy from half a pixel the pairs that agree with each other place the frames.
  // From the online chain a Huber solve comes first (links it left pixels off are not discounted
  // before the poses come near them); poses the focal length's search solved start the Cauchy
  // solve themselves. Per-patch error on 46 surveys of bench/run_engine_spread.py, one draw
  // each: a geometric mean of 0.87 of Huber's alone, 39 better, 6 worse (small-degraded +15 %
  // over four draws; bench/RESULTS.md, session 41).
  double robust_loss_px = 0.5;
  static constexpr int kFocalPairs = 32;
  int max_pairs_per_link = 400;  // every pair counts: thinner links cost accuracy
  double max_rms_px = 2.5;  // an adjustment that leaves a larger transfer error is not used

  bool IsValid(std::string* error) const;
};

struct PatchAdjustment {
  bool used = false;            // the adjusted placements replace the online ones
  // Why not, when not: for callers to act on (`note` is for people).
  enum class Miss {
    kNone,
    kOff,           // not asked for
    kTooFewFrames,  // under three frames: nothing to adjust
    kFailed,        // the solver gave up
    kMisfit,        // solved, but the frames fit no flat ground seen through a pinhole camera
  } miss = Miss::kNone;
  std::string note;             // why not, when not
  std::vector<cv::Matx33d> frame_to_patch;  // per frame, in the order given
  std::vector<PlanePose> poses;
  double focal = 0;             // pixels: as given, or as refined
  // Groups of frames whose links did not reach the rest, tied to the frame before them by their
  // online placements (otherwise free in the solve).
  int ties = 0;
  PlaneAdjustment stats;
};

// `indices` and `online` are the patch frames (sequence numbers, online frame -> patch
// homographies, the first frame's being the identity); links refer to sequence numbers, and may
// name frames outside the patch only if they are in `indices` too.
PatchAdjustment AdjustPatch(const std::vector<int>& indices, const std::vector<cv::Matx33d>& online,
                            const std::vector<FrameLink>& links, double focal, cv::Size frame,
                            const PatchAdjustmentOptions& options);

}  // namespace rolamos
