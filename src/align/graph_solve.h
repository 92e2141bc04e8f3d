// The global map's solve (rolamos align, stages 5 and 6): every frame a camera over the seafloor
// plane, each connected part adjusted on its own by Ceres (Cauchy loss on each edge, edges found
// false dropped), and loop closures between frames the solution puts over the same ground.
#pragma once

#include <map>
#include <vector>

#include <opencv2/core.hpp>

#include "align/frame_graph.h"
#include "geometry/plane_adjustment.h"

namespace rolamos {

struct GraphSolution {
  std::vector<PlanePose> poses;              // per node
  std::vector<char> dropped;                 // per edge: found false by the adjustment
  std::map<int, std::vector<int>> members;   // part root -> its nodes
  std::map<int, int> anchor;                 // part root -> the node held fixed (its gauge)
};

// Level cameras where the first placement puts the frames; each part anchored at its
// best-linked node (the most edges), not its first: a first frame with a weak first
// registration must not hold the whole part where it is.
GraphSolution StartSolution(const FrameGraph& g, const std::vector<cv::Matx33d>& G, UnionFind& comp);

// The largest transfer RMS (frame pixels) of an engine link within a patch that the solve
// found false; 0 when none was.
double WorstDroppedChainLink(const FrameGraph& g, const GraphSolution& s);

// Every part adjusted on its own, in parallel; `priors` (navigation) when given. With
// `trust_chain`, the engine's links are never found false and keep their pull however far off
// they are (PlaneLink::trusted). Returns the edges newly found false.
int AdjustParts(const FrameGraph& g, GraphSolution& s, const std::vector<GroundPrior>& priors, const AlignOptions& o,
                const ParallelForOptions& pfo, bool trust_chain = false);

// Transfer error of every kept edge, frame pixels (RMS).
double KeptEdgesRms(const FrameGraph& g, const GraphSolution& s);

// One round of loop closures: frames of the same part the solution puts over the same ground
// (overlap >= loop_overlap), apart in the sequence and not linked yet, verified (kLoop edges).
// Returns the edges added.
int AddLoopClosures(FrameGraph& g, GraphSolution& s, UnionFind& comp, const AlignOptions& o, AlignSummary* summary,
                    const ParallelForOptions& pfo);

// A node's placement (frame -> plane) in the solution.
cv::Matx33d NodeToPlane(const FrameGraph& g, const GraphSolution& s, int i);

// The loop closures found so far out of the graph, their pairs free to be found again: they
// stand on the placement they were found under.
void RemoveLoopClosures(FrameGraph& g);

}  // namespace rolamos
