// The global map's first placement (rolamos align, stage 4), before any adjustment: within a patch
// the engine's own placements (already adjusted together), between patches a spanning tree of
// their strongest edges (the engine's links first), so that few estimates are chained. Also what
// the consistency check compares appearance edges with (the engine's links alone).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "align/frame_graph.h"

namespace rolamos {

// Every node's frame -> plane homography, each connected part's first node (its root) the
// reference: the level camera over it (its centre, heading and scale) sees the plane pixel for
// pixel. `comp` is filled with the parts the used edges make.
// `usable[k]`: edge k may be used (empty: every edge).
std::vector<cv::Matx33d> PlaceFirst(const FrameGraph& g, UnionFind* comp, const std::vector<char>& usable = {});

}  // namespace rolamos
