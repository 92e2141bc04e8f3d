// The global map's graph (rolamos align, stages 1-3): one node per keyframe of the survey, with
// its stored features; edges from the engine's links, appearance retrieval over every frame and,
// later, loop closures, each verified by a RANSAC homography.
#pragma once

#include <map>
#include <set>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "rolamos/global_align.hpp"
#include "rolamos/store.hpp"
#include "store/frame_data.h"
#include "util/parallel_for.h"

namespace rolamos {

struct GraphNode {
  int patch = 0;         // patch id
  size_t record = 0;     // index in the patch's frames
  int index = 0;         // sequence number
  std::string source;
  cv::Matx33d to_patch;  // the online placement
  std::vector<cv::Point2f> points;
  cv::Mat descriptors;   // CV_8U, n x 128
  // The first `primary` features are matched first (and describe the frame for retrieval); the
  // rest only where those do not link a pair (kPrimaryStoredFeatures). 0 = all of them.
  int primary = 0;
};

enum EdgeKind { kOnline = 0, kRetrieval = 1, kLoop = 2 };

struct GraphEdge {
  int a = 0, b = 0;
  std::vector<cv::Point2f> in_a, in_b;
  EdgeKind kind = kOnline;
  // Once compressed (CompressEdge): a few points of the homography the matched pairs fit, each
  // weighing as the pairs it stands for (weight^2 of them; empty: 1 each), and the pairs' RMS
  // scatter about that fit, frame pixels.
  std::vector<float> weight;
  float scatter_px = 0;
  int matches = 0;  // matched pairs the edge was measured from (0: in_a.size())

  int Matches() const { return matches > 0 ? matches : static_cast<int>(in_a.size()); }
};


// Union-find over frames.
struct UnionFind {
  std::vector<int> parent;
  explicit UnionFind(size_t n);
  int Find(int i);
  bool Join(int a, int b);
};

// A frame the engine followed between keyframes: not in the graph, carried along afterwards by its
// keyframe (patch id, record, keyframe index).
struct FollowedFrame {
  int patch = 0;
  size_t record = 0;
  int keyframe = -1;
};

struct FrameGraph {
  std::map<int, PatchSidecar> sidecars;
  std::vector<GraphNode> nodes;
  std::map<FrameId, int> node_of;
  std::vector<FollowedFrame> followed;
  std::vector<GraphEdge> edges;
  std::set<std::pair<int, int>> linked;  // node pairs with an edge, (low, high)
  cv::Mat appearance;  // each node's appearance vector (DescribeFrames), once retrieval described them
  cv::Size frame;
  double focal = 0;
  cv::Matx33d K = cv::Matx33d::eye();

  int size() const { return static_cast<int>(nodes.size()); }
  void AddLinked(int a, int b) { linked.emplace(std::min(a, b), std::max(a, b)); }
  bool Linked(int a, int b) const { return linked.count({std::min(a, b), std::max(a, b)}) > 0; }
  // Frames of one patch closer in the sequence than `gap`: the chain links them already.
  bool NearInSequence(int i, int j, int gap) const {
    return nodes[size_t(i)].patch == nodes[size_t(j)].patch && std::abs(nodes[size_t(i)].index - nodes[size_t(j)].index) < gap;
  }
};

// Stages 1 and 2: every keyframe of the store with its stored features (described again from its
// file when a patch has none stored), and the edges the engine found (its stored links, or for
// older stores the online placements of consecutive frames). Fills `summary`'s frame counts.
FrameGraph LoadFrameGraph(const Store& store, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo);

// Stage 3: appearance retrieval over every frame, each candidate verified (kRetrieval edges).
void AddRetrievalEdges(FrameGraph& g, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo);
// When the edges so far leave the graph in parts: retrieval again between frames of different
// parts only, with AlignOptions::rejoin_candidates and rejoin_min_inliers (light-cone's lanes,
// joined across the frames' dark edges, had 15-24 inliers where 25 are asked). The edges are
// appearance edges like the others, checked for consistency after.
void AddRejoiningEdges(FrameGraph& g, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo);

// At most `n` pairs spread over frame a (Thin's grid), as the optimisation wants them.
GraphEdge ThinEdge(GraphEdge e, int n, cv::Size frame);

// The edge's pairs replaced by the homography they fit (under a Cauchy loss from `loss_px`, or
// by least squares with 0), at most `points` weighted points (geometry/pair_compression.h),
// their scatter kept; as it is when that gains nothing.
GraphEdge CompressEdge(GraphEdge e, int points, double loss_px = 0);

// What align does with every edge it finds: thinned to pairs_per_edge, compressed to
// points_per_edge.
GraphEdge MeasureEdge(GraphEdge e, const AlignOptions& o, cv::Size frame);

// Two frames that see the same ground, for real: matches one RANSAC homography explains, a motion
// a camera over the seafloor can make, enough inliers covering some of the frame. `guess`
// (a -> b), when given, guides the matching. The frames' primary features are matched first,
// all of them when those give some matches (10) but no such verified pairs.
bool VerifyPair(const GraphNode& a, const GraphNode& b, const cv::Matx33d* guess, cv::Size frame, const AlignOptions& o,
                GraphEdge* out);

double Median(std::vector<double> v);

}  // namespace rolamos
