// Appearance edges must agree with the rest of the map before any placement rests on them
// (rolamos align). Look-alike ground (sand ripples, rubble, nets, a quarter of a site that repeats
// another turned about) gives false matches that agree with each other, the same wrong offset
// over many frames: a robust loss alone lets such a self-consistent set fold the map.
//
// - Within one part of the engine's chain (frames its links join): an edge's relative placement
//   is compared with the chain's. The chain drifts with the distance along it, but not by a
//   frame's size, or a half turn, over a few hundred frames: an edge that disagrees by more than
//   the drift allows is dropped.
// - Between parts the chain does not join: the edges are grouped by the placement of one part on
//   the other they imply (pairwise consistent sets). The set the navigation supports wins when
//   there is navigation; otherwise each set is checked by its consequence - placed so, the two
//   parts overlap elsewhere too, and there their frames must match (verified pairs). A set whose
//   overlap does not match, or that loses, is dropped and reported with the frames it joined.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "align/frame_graph.h"

namespace rolamos {

// A frame's navigation: the map position of a pixel of node `node`.
struct NavigationFix {
  int node = 0;
  cv::Point2d pixel, map;
};

struct ConsistencyReport {
  std::vector<char> drop;  // per edge of the graph
  int dropped_edges = 0;
  std::vector<RejectedJoin> rejected;  // what was dropped, with the frames it joined
};

ConsistencyReport CheckAppearanceEdges(const FrameGraph& g, const AlignOptions& o, const std::vector<NavigationFix>& nav,
                                       const ParallelForOptions& pfo);

// The edges marked out of the graph (their pairs stay "linked": not tried again).
void RemoveEdges(FrameGraph& g, const std::vector<char>& drop);

}  // namespace rolamos
