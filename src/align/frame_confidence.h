// Where the map is sure and where it rests on little (rolamos align, after the solve).
//
// Per frame: the residual of its edges (their matched pixels' transfer error through the solution)
// and an uncertainty, in pixels of the map. The uncertainty follows how the frame is held: a
// frame among many consistent edges is known to about its residual over the square root of its
// edges; a part of the map that joins the rest through a single link (a bridge of the graph: a
// lane joined by one pair of frames) can swing about that link, so its frames inherit the link's
// error times the lever of their distance from it, added up over every such link between them and
// the part's anchor.
//
// A frame whose own edges it sits far from (its residual many times its neighbours', or none left)
// is placed again from its edges with its neighbours held; if that fails it is flagged, never
// drawn silently as if sure.
#pragma once

#include <vector>

#include "align/frame_graph.h"
#include "align/graph_solve.h"

namespace rolamos {

struct FrameConfidence {
  double residual_px = 0;     // RMS transfer error of its kept edges
  int edges = 0;              // its kept edges
  double uncertainty_px = 0;  // how far it may be from where the map puts it (1 sigma, roughly)
  bool replaced = false;      // placed again from its own edges after the solve
  bool doubtful = false;      // still far off its edges, or without any
  // Onto the frame's record (the sidecar fields residual_px, uncertainty_px, align_edges,
  // placement_doubtful).
  void WriteTo(FrameRecord* record) const;
};

// Judges every node of the solution (and re-places the few that sit far off their own edges);
// fills the summary's doubtful frames and regions.
std::vector<FrameConfidence> AssessFrames(const FrameGraph& g, GraphSolution& s, const AlignOptions& o,
                                          AlignSummary* summary);

// The uncertainty model alone, for a graph of `n` frames with `edges` (node pairs), each with its
// residual: bridges and the lever of each frame's distance from them (frame centres `centre`,
// pixels; lever unit `diag`). `anchor` per part (node -> anchor node of its part).
std::vector<double> GraphUncertainty(int n, const std::vector<std::pair<int, int>>& edges,
                                     const std::vector<double>& edge_residual, const std::vector<cv::Point2d>& centre,
                                     const std::vector<int>& anchor_of, double diag);

}  // namespace rolamos
