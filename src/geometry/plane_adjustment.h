// Bundle adjustment of camera poses over the seafloor plane (Ceres Solver): every pair of frames
// that see the same ground contributes its matched pixels; a pixel of frame a, cast onto the plane
// through a's pose and seen by b, must land on its match in b. A robust loss (Huber or Cauchy)
// keeps a false match or a false loop from bending the map, and the sparse solver takes surveys
// of thousands of frames. Used for each patch as it closes (the engine) and for the whole survey
// (the global map), with navigation entering as weighted priors on the camera centres.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "geometry/plane_camera.h"

namespace rolamos {

// Matched pixels between frames a and b (indices into the poses).
struct PlaneLink {
  int a = 0, b = 0;
  std::vector<cv::Point2f> in_a, in_b;
  // Multiplies every residual of the link; a link's own robust loss (PlaneAdjustmentOptions::
  // per_link) has its knee multiplied too, so that it stays at the same error of the link's pixels.
  double weight = 1.0;
  // Per pair (empty: 1 each): multiplies that pair's residuals. A pair of weight w stands for w^2
  // matched pairs (an edge's homography sampled at a few points, each for the pairs about it).
  std::vector<float> pair_weight;
  // The RMS scatter of the matched pairs about the points (a compressed link: the pairs' distance
  // from the homography they fit). Reported in the transfer error as those pairs would count it;
  // the solve does not see it (no pose changes it).
  double scatter_px = 0;
  // A link the others must agree with (the engine's chain of consecutive frames, verified as it
  // was made): never dropped, not discounted by the robust loss, and ten times the weight, so
  // that a group of frames other links pulled away is pulled back by it and those links become
  // the outliers.
  bool trusted = false;
};

// Where the ground under a pixel of a frame is known to be (navigation: usually the frame's
// centre), in map pixels, with its standard deviation.
struct GroundPrior {
  int frame = 0;
  cv::Point2d pixel;  // of the frame
  cv::Point2d xy;     // on the plane
  // Its standard deviation, in the units of the links' residuals: pixels, or (align) pixels over
  // the matched pixels' own sigma.
  double sigma_px = 1.0;
};

struct PlaneAdjustmentOptions {
  std::string loss = "huber";  // huber | cauchy: how residuals beyond loss_px are discounted
  double loss_px = 1.0;
  int max_iterations = 50;
  // The focal length as one more unknown, shared by all frames, within a factor of 3 of the one given.
  bool refine_focal = false;
  double max_tilt_deg = 25.0;  // roll and pitch are held within this
  int threads = 1;
  // A link whose matches stay further apart than this after a solve (RMS, frame pixels) is taken
  // for a false one and dropped, and the poses solved again (up to `rounds` times): a wrong
  // registration must not bend everything around it. 0 = keep every link.
  double drop_link_px = 4.0;
  int rounds = 3;
  // One residual block (and one robust loss) per link rather than per matched pixel: a false
  // link is discounted as a whole, and surveys of thousands of frames build a small problem.
  bool per_link = false;

  bool IsValid(std::string* error) const;
};

struct PlaneAdjustment {
  bool ok = false;
  std::string message;        // Ceres's reason when not ok
  int residuals = 0;          // matched pixel pairs used
  double initial_rms_px = 0;  // transfer error before and after, frame pixels
  double final_rms_px = 0;
  int iterations = 0;
  int links_dropped = 0;
  std::vector<char> dropped;  // per link given: dropped as false
  double seconds = 0;
};

// Adjusts `poses` (and `focal`, with refine_focal) to the links and priors. The gauge: without
// priors, pose `anchor` keeps its centre and heading (its roll and pitch are adjusted: they are
// measured against the plane); frames marked in `held` (may be empty) keep their whole pose.
PlaneAdjustment AdjustPlanePoses(std::vector<PlanePose>* poses, double* focal, cv::Size frame,
                                 const std::vector<PlaneLink>& links, int anchor,
                                 const std::vector<char>& held, const std::vector<GroundPrior>& priors,
                                 const PlaneAdjustmentOptions& options);

// RMS transfer error of the links under the poses (frame pixels), as the adjustment reports it:
// each pair counted pair_weight^2 times, a compressed link's scatter included.
double PlaneTransferRms(const std::vector<PlanePose>& poses, double focal, cv::Size frame,
                        const std::vector<PlaneLink>& links);

}  // namespace rolamos
