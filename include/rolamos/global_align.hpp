// The global map: one graph of the whole survey and one robust optimisation of every frame's
// placement (`rolamos align`).
//
// Nodes are the frames of every patch. Edges come from three sources, each verified by matched
// pixels that one RANSAC homography explains: the engine's own links (stored with each patch),
// appearance retrieval over every frame (VLAD of its stored SIFT features), and loop closures
// between frames that the first solution puts over the same ground. Every frame is a camera over
// the seafloor plane (geometry/plane_camera.h), adjusted to all edges at once by Ceres with a
// Cauchy loss on each edge, so one false loop cannot bend the map; navigation, when given, pulls
// the camera centres as weighted priors. Before any placement rests on them, appearance edges are
// checked against the engine's chain and against each other (align/edge_consistency.h): look-alike
// ground that matches at the wrong place in a self-consistent set is dropped and reported. After
// the solve each frame gets its residual and an uncertainty (align/frame_confidence.h), and the
// regions the map is unsure of are named. Parts that share no ground become separate components,
// placed side by side. Each frame records its placement (frame_to_global) and each patch its
// component and the homography that best carries it there; `compose` then draws every frame
// where it belongs. The store changes in one atomic step at the end: an interrupted align leaves
// it as it was.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "rolamos/georeference.hpp"
#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct AlignOptions {
  // Where the frames are, for patches written without stored features (an older rolamos): their
  // frames are read and described again. "" = where the sidecars say.
  std::string frames_dir;
  int retrieval_candidates = 5;  // most similar frames tried per frame (appearance)
  int vocabulary = 32;           // VLAD words
  int loops_per_frame = 4;       // spatial neighbours tried per frame under the first solution
  double loop_overlap = 0.2;     // footprint overlap that makes two frames spatial neighbours
  int min_index_gap = 8;         // frames of one patch closer in the sequence are chain neighbours
  int min_inliers = 25;          // an edge needs this many RANSAC inliers
  // When the engine's links and retrieval leave the map in parts (lanes joined only across the
  // dark edges of a light cone, or a degraded lane): frames are matched again with frames of the
  // other parts only, this many candidates each, an edge needing this many inliers. 0
  // candidates = never.
  int rejoin_candidates = 15;
  int rejoin_min_inliers = 15;
  // Matched pixels kept per edge, spread over the overlap: the edge's measurement is the
  // homography they fit. The map's low-frequency shape (a bow across 80 lanes) is what the
  // pairs' noise adds up to, so more pairs are a truer map (bench/RESULTS.md, 2026-11-26 (4)).
  // As many as the engine stores a link (192; 48 before session 53): 0.84 of the error after
  // align over 18 stills surveys, 0.94 over 18 MPEG-4 ones, links.json ~2.2 times larger; a
  // store written with 48 a link gains only on the edges align matches itself; 10,000 frames
  // of the procedural seafloor are worse, 0.25 -> 0.28 px (bench/RESULTS.md, session 53).
  int pairs_per_edge = kMaxStoredLinkPairs;
  // Points at which the solve compares each edge's homography with the map (a grid over its
  // pairs, each point weighing as the pairs it stands for; at least 9). The solver's memory grows
  // with these, not with the pairs: 0 = no compression, every kept pair in the solve.
  int points_per_edge = 9;
  double loss_px = 1.0;          // Cauchy knee: an edge whose RMS passes this is discounted
  // Each edge weighs by how closely its matched pairs fit its homography, as the inverse of their
  // scatter (floored at this) against the edges' median: the engine's links, pixels it followed
  // to a tenth of a pixel, weigh more than matches of SIFT's stored features half a pixel off,
  // where by their pairs alone each weighed the same and the map within a lane came out twice the
  // engine's error (bench/RESULTS.md, 2026-12-01 (43)). 0 = by their pairs alone, as before.
  double scatter_floor_px = 0.1;
  // Each edge's homography is fitted to its pairs under a Cauchy loss from this many pixels, as
  // the engine's adjustment discounts each pair on its own: by least squares, a few pairs a pixel
  // or more off (a corner followed onto its neighbour) bent the edge (bench/RESULTS.md,
  // 2026-12-01 (43)). 0 = least squares, as before. Only where edges are compressed.
  double edge_loss_px = 0.5;
  // Per-frame navigation (ReadNavigationCsv): each camera centre pulled towards it.
  std::map<std::string, FrameNavigation> navigation;
  double navigation_sigma_m = 0.5;  // how far a centre may stray from its navigation (1 sigma)
  int threads = 0;                  // 0 = one per core
  // An appearance edge must agree with the engine's chain within this many frame diagonals, plus
  // chain_drift of a diagonal for each frame of the chain between its two frames; and between
  // parts the chain does not join, the edges of one set within this of each other.
  double chain_tolerance = 0.25;
  double chain_drift = 0.0005;
  // A link of the engine's chain within a patch that the solve finds false this far off (frame
  // pixels) means a group of frames was pulled away, not a noisy link: the graph is solved again
  // with the chain first.
  double chain_break_px = 100.0;
  // After the solve: a frame whose edges' residual passes this (and five times the typical one) is
  // placed again or flagged; regions whose uncertainty passes doubtful_px (and five times the
  // typical one) are named.
  double frame_residual_px = 3.0;
  double doubtful_px = 2.0;

  bool IsValid(std::string* error) const;
};

// A set of appearance edges dropped because it disagreed with the rest of the map.
struct RejectedJoin {
  std::string reason;
  int edges = 0;
  std::string joined;  // "frames 120-135 (patch 4) with frames 610-630 (patch 19)"
};

// Frames of one patch the map is unsure of (high uncertainty, or placement doubtful).
struct DoubtfulRegion {
  int patch = 0;
  int first_frame = 0, last_frame = 0;  // sequence numbers
  int frames = 0;
  int doubtful_frames = 0;              // far off their own edges even after being placed again
  double worst_uncertainty_px = 0;
};

struct AlignSummary {
  int frames = 0;
  int frames_described = 0;      // read and described again (no stored features)
  int online_edges = 0;
  int retrieval_tried = 0, retrieval_edges = 0;
  // When the engine's links and retrieval leave the map in parts: pairs of frames in different
  // parts tried again with AlignOptions::rejoin_candidates and rejoin_min_inliers, and the edges
  // found (checked for consistency like every appearance edge).
  int rejoin_tried = 0, rejoin_edges = 0;
  int loop_tried = 0, loop_edges = 0;
  int edges_dropped = 0;          // found false by the optimisation
  // The worst engine link within a patch found false (frame pixels); past
  // AlignOptions::chain_break_px the graph was solved again with the chain first.
  double chain_break_px = 0;
  int edges_inconsistent = 0;     // appearance edges that disagreed with the chain or each other
  std::vector<RejectedJoin> rejected_joins;
  int frames_replaced = 0;        // far off their edges after the solve, placed again from them
  int frames_doubtful = 0;        // still far off, or without any edge: flagged
  double median_uncertainty_px = 0;
  std::vector<DoubtfulRegion> doubtful_regions;  // most uncertain first
  int components = 0;
  std::vector<int> component_frames;  // frames per component, largest first
  double rms_before_px = 0;       // transfer error of all edges, frame pixels
  double rms_after_px = 0;
  int navigation_frames = 0;
  double navigation_before_m = 0;  // median distance of frame centres from their navigation
  double navigation_after_m = 0;
  double seconds = 0;
  // Each stage in order: its name, seconds, and the process's peak memory (MiB) at its end.
  struct Stage {
    std::string name;
    double seconds = 0;
    double peak_mib = 0;
  };
  std::vector<Stage> stages;
};

AlignSummary AlignStore(Store store, const AlignOptions& options, const ProgressFn& progress = {});

}  // namespace rolamos
