// Global alignment of a store (after `compose` has placed the patches): frames of different times
// that see the same ground (neighbouring lawnmower lanes, crossing tracks) are matched, and a
// similarity or affine correction of every frame's online placement is solved for by sparse linear least
// squares, so that drift along the survey does not accumulate. Consecutive frames keep their
// online relative placement as constraints; the first frame is held. Each patch's
// `patch_to_global` becomes the homography that best carries its frames to their corrected
// places (the online one is kept as "patch_to_global_online"), and every frame records its
// corrected "frame_to_global"; `compose` then draws the aligned mosaic.
#pragma once

#include <functional>
#include <map>
#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/georeference.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct AlignOptions {
  std::string frames_dir;        // where the frames are, when not where the sidecars say
  std::string model = "affine";  // correction of each frame's placement: similarity or affine
  // Frames whose centres are closer than this x frame width are tried, if at least min_index_gap
  // apart in the sequence: with 80 % forward overlap, the nearest frames of a lane are its own
  // next ones, which the chain links already and which show no drift; with a gap of 4 and a
  // radius of 0.5 a 1,000-frame lawnmower survey found only those (loop error 0.8 px, global
  // error 77 px left uncorrected); with 20 and 1.0 it found the neighbouring lanes (121 px ->
  // 0.3 px, global 11.7 px), at 1.85 px instead of 1.46 on the 300-frame survey.
  double search_radius = 1.0;
  int min_index_gap = 20;
  int max_pairs_per_frame = 1;   // nearest later candidates tried per frame (more were worse)
  int min_inliers = 40;          // a loop pair needs this many homography inliers
  double chain_weight = 1.0;     // of the online frame-to-frame placements
  double loop_weight = 1.0;      // of a loop pair's matched points
  double min_loop_error_px = 1.5;  // loops closing better than this (RMS) leave the map as it is
  // Per-frame navigation (ReadNavigationCsv), when known: each frame is also pulled towards where
  // the navigation puts it (through one similarity from global pixels to the map, refitted as the
  // solution moves), so the scale drift that vision alone cannot see is corrected too.
  std::map<std::string, FrameNavigation> navigation;
  double navigation_weight = 0.2;  // of a navigation point, against 1 for a matched point

  bool IsValid(std::string* error) const;
};

struct AlignSummary {
  int frames = 0;
  int chain_links = 0;
  int pairs_tried = 0, pairs_found = 0;
  bool corrected = false;           // false: the loops already closed (or none was found)
  double loop_error_before_px = 0;  // RMS distance of loop pairs' matched points, global pixels
  double loop_error_after_px = 0;
  int navigation_frames = 0;        // frames with navigation
  double navigation_before_m = 0;   // median distance of frame centres from their navigation
  double navigation_after_m = 0;    // (one similarity fitted from the placement to the map)
  double seconds = 0;
};

AlignSummary AlignStore(Store store, const AlignOptions& options, const ProgressFn& progress = {});

}  // namespace rolamos
