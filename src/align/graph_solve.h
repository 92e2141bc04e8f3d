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

// Each part's plane scaled (about its origin) so that its typical frame (the median altitude)
// spans as many map pixels as it has: the gauge is otherwise the anchor's, and a chain that
// drifted in scale (twice, five times over thousands of frames) would draw, and compose, the
// whole map at that scale. Applied to the first placement and to the solution.
void ScaleToTypicalFrame(const FrameGraph& g, GraphSolution& s);

// The largest transfer RMS (frame pixels) of an engine link within a patch that the solve
// found false; 0 when none was.
double WorstDroppedChainLink(const FrameGraph& g, const GraphSolution& s);

// How an adjustment weighs the edges.
enum class AdjustMode {
  // Cauchy at AlignOptions::loss_px; edges left more than three times that off are found false.
  kJudge,
  // The engine's links never found false and keeping their pull however far off they are
  // (PlaneLink::trusted); nothing dropped: the chain drifts along a lane, and a true loop
  // closure measured against its drift would look false.
  kTrustChain,
  // Cauchy at ten times loss_px, nothing dropped: from a placement tens of pixels off (the
  // chain's drift), the true edges pull it back before they are judged.
  kWide,
};

// Every part adjusted on its own, in parallel (a lone part's solver gets every thread);
// `priors` (navigation) when given. Returns the edges newly found false.
int AdjustParts(const FrameGraph& g, GraphSolution& s, const std::vector<GroundPrior>& priors, const AlignOptions& o,
                const ParallelForOptions& pfo, AdjustMode mode = AdjustMode::kJudge);

// An edge as the plane adjustment takes it (its points, their weights, the pairs' scatter), between
// nodes `a` and `b` of the problem.
PlaneLink LinkOf(const GraphEdge& e, int a, int b);

// The median scatter of the compressed edges' pairs about their homographies (frame pixels; 0
// when no edge is compressed).
double TypicalScatter(const FrameGraph& g);

// How much an edge weighs beside the others (PlaneLink::weight): `typical` over its pairs' scatter
// floored at `floor_px`, as the inverse of the error its homography carries. 1 for an edge
// without a scatter (not compressed), or with `floor_px` or `typical` 0.
double ScatterWeight(const GraphEdge& e, double typical, double floor_px);

// Transfer error of every kept edge, frame pixels (RMS over the matched pairs).
double KeptEdgesRms(const FrameGraph& g, const GraphSolution& s);

// One round of loop closures: frames of the same part the solution puts over the same ground
// (overlap >= loop_overlap), apart in the sequence and not linked yet, verified (kLoop edges).
// Returns the edges added.
int AddLoopClosures(FrameGraph& g, GraphSolution& s, UnionFind& comp, const AlignOptions& o, AlignSummary* summary,
                    const ParallelForOptions& pfo);

// A node's placement (frame -> plane) in the solution.
cv::Matx33d NodeToPlane(const FrameGraph& g, const GraphSolution& s, int i);

// Rounds of loop closures under the solution, each followed by an adjustment (`mode`), while a
// round finds more than a hundredth of the loop closures so far (at most four).
void CloseLoops(FrameGraph& g, GraphSolution& s, UnionFind& comp, const AlignOptions& o, const ParallelForOptions& pfo,
                AdjustMode mode, AlignSummary* summary);

// Stages 5-6 from a first placement: the adjustment, then loop closures under it. With
// `trust_chain`, the engine's chain decides first where groups of frames go (a group other links
// pulled away comes back, and those links become the outliers); then every link is judged from
// there, after a wide-loss pass that lets the loop closures undo the chain's drift.
GraphSolution SolveGraph(FrameGraph& g, GraphSolution s, UnionFind& comp, const AlignOptions& o,
                         const ParallelForOptions& pfo, bool trust_chain, AlignSummary* summary);

// The loop closures found so far out of the graph, their pairs free to be found again: they
// stand on the placement they were found under.
void RemoveLoopClosures(FrameGraph& g);

}  // namespace rolamos
