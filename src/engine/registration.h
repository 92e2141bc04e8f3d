// Registration of a new frame to the open patch, beyond the paper's frame-to-frame step:
// - how well a registration is supported (inliers, their spread over the frame, a homography that
//   is well conditioned and a plausible motion), so that the motion model arbitrates between
//   candidates instead of vetoing a real change of course;
// - guided matching against any frame of the patch, where the current estimate puts the features;
// - the frame's placement fitted against every patch frame it overlaps (the paper aligns the
//   observation to the existing mosaic), so that error does not accumulate from pair to pair.
#pragma once

#include <optional>

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/egomotion.h"
#include "engine/features.h"

namespace rolamos {

struct SupportOptions {
  int strong_inliers = 40;      // at least this many homography inliers...
  double min_spread = 0.06;     // ...covering this much of the frame (convex hull / frame area)
  double max_scale_change = 1.6;   // singular values of the linear part within [1/x, x]
  double max_anisotropy = 1.35;    // and their ratio below this
  // Relative scale change across the frame from the projective terms. A camera that pitches by 8
  // degrees between two frames changes it by 0.25 at 70 degrees across, 0.37 at 90 (from 0.3 a
  // jittered wide-angle video lost frames as implausible: bench/RESULTS.md, session 21); false
  // registrations on repetitive or dark ground are wilder than this.
  double max_perspective = 0.6;

  bool IsValid(std::string* error) const;
};

struct Support {
  int inliers = 0;
  double spread = 0;         // convex hull of the inliers / frame area
  bool conditioned = false;  // a homography a camera over a plane can produce
  bool strong = false;       // enough of everything to stand on its own
  std::string weakness;      // why not strong
};

Support AssessSupport(const EgomotionResult& r, cv::Size frame, const SupportOptions& options);
// Whether H (frame -> frame) is a motion a camera over a roughly flat seafloor can make.
bool IsPlausibleMotion(const cv::Matx33d& H, cv::Size frame, const SupportOptions& options);

// Matches of `a`'s features among `b`'s near where `a_to_b` puts them (within `radius` pixels),
// with the ratio test among those candidates only. Far cheaper than a full match and finds more.
Matches MatchGuided(const Features& a, const Features& b, const cv::Matx33d& a_to_b, double radius,
                    double ratio);

// Matches verified by a RANSAC homography (3 px).
struct VerifiedMatch {
  int inliers = 0;          // 0: no homography verified the matches
  cv::Matx33d H;            // a's pixels -> b's pixels
  Matches matches;
  std::vector<uchar> inlier;  // per match
  // The pairs the homography fits.
  void Inliers(std::vector<cv::Point2f>* a, std::vector<cv::Point2f>* b) const;
};

// `m` verified; inliers stays 0 when fewer than `min_inliers` agree.
VerifiedMatch VerifyByHomography(Matches m, int min_inliers);

// Ratio- and mutual-checked matches of a against b (MatchFeatures), verified.
VerifiedMatch MatchVerified(const Features& a, const Features& b, const FeatureOptions& options, int min_inliers);

// Matched pixels between two frames of the input (their sequence numbers).
struct FrameLink {
  int a = 0, b = 0;
  std::vector<cv::Point2f> in_a, in_b;
};

// A frame of the open patch, as new frames are registered against it.
struct PatchFrame {
  int index = 0;
  std::shared_ptr<const Features> features;
  cv::Matx33d to_patch = cv::Matx33d::eye();
};

// Fraction of frame A (warped by a_to_patch) that frame B covers, both of `size`.
double FootprintOverlap(const cv::Matx33d& a_to_patch, const cv::Matx33d& b_to_patch, cv::Size size);

struct PatchFitOptions {
  // Patch frames the new one is fitted against, besides the previous. With keyframes every 15 %
  // of a frame (video), 4 recent ones hold a patch as 6 did, for a third less matching.
  int max_frames = 4;
  // Only the patch's most recent frames place a new one online: older ones (an earlier lane)
  // may have drifted against them, and pulling the frame towards both would distort it. The
  // older frames it overlaps are linked to it for the adjustment at closing instead.
  int recent_frames = 6;
  double loop_radius = 48.0;     // guided matching radius against the older frames, pixels
  // How far (a fraction of the frame's diagonal) the chain may have drifted from an older lane
  // for a loop link found by matching all features to be kept; 0 = guided loop links only.
  double loop_drift = 0.3;
  int max_loop_frames = 2;
  double min_overlap = 0.12;     // a patch frame is used when it covers this much of the new one
  double search_radius = 12.0;   // guided matching radius, pixels
  double ratio = 0.85;
  double inlier_px = 2.0;        // final fit's outlier threshold
  double max_correction_px = 12.0;  // a fit that moves the corners further is not trusted

  bool IsValid(std::string* error) const;
};

struct PatchFit {
  bool ok = false;
  cv::Matx33d to_patch = cv::Matx33d::eye();
  int frames = 0;    // patch frames that contributed (the previous one included)
  int inliers = 0;
  double correction_px = 0;  // how far the fit moved the corners from the guess
  std::vector<FrameLink> links;  // the inlier matches with each patch frame (a = the new frame)
};

// The matches of a frame (of `size`) placed at `to_patch` with an older patch frame under it,
// guided by the placements and verified by a RANSAC homography; none when fewer than 20 agree.
// Where the guided search finds too few, the two frames are matched over all their features
// that may overlap, and a link within PatchFitOptions::loop_drift of the placements is kept,
// with the frame's placement it implies in `placed` (an empty `size`: guided only).
std::optional<FrameLink> LinkPair(int index, const Features& frame, const cv::Matx33d& to_patch,
                                 const PatchFrame& older, const PatchFitOptions& options, cv::Size size,
                                 cv::Matx33d* placed);

// Pairs between a new frame and patch frames under it: the new frame's point, where its match
// lies in the patch, the match in its own frame, and which frame that is.
struct PatchPairs {
  std::vector<cv::Point2f> in_frame, in_patch, in_other;
  std::vector<int> other;
  void Add(cv::Point2f p, const cv::Matx33d& other_to_patch, cv::Point2f q, int who);
  size_t size() const { return in_frame.size(); }
};

// A homography (new frame -> patch) fitted by least squares in three rounds, each dropping the
// pairs farther than max(inlier_px, 3 x the median residual), the first no nearer than
// `first_cut_px`. It starts from `guess`: the pairs were found near it already, so the guess is a
// robust start where RANSAC would only cost time. Not ok when fewer than 12 pairs survive.
struct TrimmedFit {
  bool ok = false;
  cv::Matx33d H = cv::Matx33d::eye();
  std::vector<uchar> keep;  // per pair, kept by the last round
  int inliers = 0;          // pairs the last completed round fitted
};
TrimmedFit FitTrimmedHomography(const PatchPairs& pairs, const cv::Matx33d& guess, double inlier_px,
                                double first_cut_px);

// The kept pairs as links from frame `index` to each other frame with 8 or more of them.
std::vector<FrameLink> LinksByFrame(int index, const PatchPairs& pairs, const std::vector<uchar>& keep);

// The new frame's placement in the patch from its matches to the previous frame (`from_prev` in
// the new frame, `to_prev` in the previous one) and to the other patch frames it overlaps.
PatchFit FitToPatch(int index, const Features& frame, cv::Size size, const cv::Matx33d& guess,
                    const PatchFrame& previous, const std::vector<cv::Point2f>& from_prev,
                    const std::vector<cv::Point2f>& to_prev, const std::vector<PatchFrame>& patch,
                    const PatchFitOptions& options);

}  // namespace rolamos
