// rolamos align: the stages in order. 1-3 the graph (align/frame_graph), the consistency of the
// appearance edges with the engine's chain (align/edge_consistency), 4 the first placement
// (align/first_placement), 5-6 the solve and loop closures (align/graph_solve), 7 navigation (here),
// each frame's residual and uncertainty (align/frame_confidence), 8 the store written (here).
#include "rolamos/global_align.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>

#include <opencv2/calib3d.hpp>

#include "align/edge_consistency.h"
#include "align/first_placement.h"
#include "align/frame_confidence.h"
#include "align/frame_graph.h"
#include "align/graph_solve.h"
#include "align/navigation_fit.h"
#include "rolamos/error.hpp"
#include "store/writer_lock.h"
#include "util/homography.h"
#include "util/memory.h"

namespace rolamos {

bool AlignOptions::IsValid(std::string* error) const {
  if (retrieval_candidates < 0 || vocabulary < 2 || loops_per_frame < 0 || min_index_gap < 1 ||
      min_inliers < 8 || rejoin_candidates < 0 || rejoin_min_inliers < 8 || pairs_per_edge < 4 || (points_per_edge != 0 && points_per_edge < 9) ||
      !(loop_overlap > 0 && loop_overlap < 1) || !(loss_px > 0) || !(scatter_floor_px >= 0) || !(edge_loss_px >= 0) ||
      !(navigation_sigma_m > 0) || threads < 0 || !(chain_tolerance > 0) || !(chain_break_px > 0)) {
    *error = "align settings are out of range (at least 8 inliers, 4 pairs and 0 or 9 points an edge, overlap in (0, 1), "
             "positive loss, navigation sigma, chain tolerance and chain break, scatter floor and edge loss 0 or more)";
    return false;
  }
  return true;
}

namespace {

// Which node carries each followed frame: the keyframe it was followed from (or its patch's
// nearest).
std::vector<int> FollowedNodes(const FrameGraph& g) {
  std::vector<int> out(g.followed.size(), -1);
  for (size_t k = 0; k < g.followed.size(); ++k) {
    const FollowedFrame& f = g.followed[k];
    auto it = g.node_of.find({f.patch, f.keyframe});
    if (it != g.node_of.end()) {
      out[k] = it->second;
      continue;
    }
    const int index = g.sidecars.at(f.patch).frames[f.record].index;
    int best = -1;
    for (const auto& [id, i] : g.node_of)
      if (id.patch == f.patch && (best < 0 || std::abs(id.index - index) < std::abs(g.nodes[size_t(best)].index - index)))
        best = i;
    out[k] = best;
  }
  return out;
}

// A navigated frame: the node it pulls (itself, or the keyframe a followed frame goes with), its
// centre in that node's pixels, and the map position of its centre.
struct NavPoint {
  int node = 0;
  cv::Point2d pixel, map;
};

std::vector<NavPoint> NavigationPoints(const FrameGraph& g, const std::vector<int>& followed_node, const AlignOptions& o) {
  std::vector<NavPoint> points;
  const cv::Point2d centre((g.frame.width - 1) / 2.0, (g.frame.height - 1) / 2.0);
  auto add = [&](const std::string& source, int node, cv::Point2d pixel) {
    const FrameNavigation* n = FindFrameNavigation(o.navigation, source);
    if (!n) return;
    const auto& t = n->geotransform;
    const double c = centre.x, r = centre.y;
    points.push_back({node, pixel, cv::Point2d(t[0] + (c + 0.5) * t[1] + (r + 0.5) * t[2],
                                               t[3] + (c + 0.5) * t[4] + (r + 0.5) * t[5])});
  };
  for (int i = 0; i < g.size(); ++i) add(g.nodes[size_t(i)].source, i, centre);
  for (size_t k = 0; k < g.followed.size(); ++k) {
    const int i = followed_node[k];
    if (i < 0) continue;
    const FrameRecord& f = g.sidecars.at(g.followed[k].patch).frames[g.followed[k].record];
    add(f.source, i, ApplyHomography(g.nodes[size_t(i)].to_patch.inv() * ToMatx(f.frame_to_patch), centre));
  }
  return points;
}

// Stage 7: the centres pulled towards their navigation, through the similarity that carries the
// plane to the map (refitted as the solution moves).
void FollowNavigation(const FrameGraph& g, GraphSolution& s, const std::vector<NavPoint>& nav, const AlignOptions& o,
                      const ParallelForOptions& pfo, AlignSummary* summary) {
  auto residual = [&](cv::Matx33d* to_map) {
    std::vector<cv::Point2d> from, to;
    for (const auto& p : nav) {
      from.push_back(ApplyHomography(NodeToPlane(g, s, p.node), p.pixel));
      to.push_back(p.map);
    }
    const auto S = FitSimilarity(from, to);
    if (!S) return -1.0;
    *to_map = *S;
    std::vector<double> d;
    for (size_t k = 0; k < from.size(); ++k) d.push_back(cv::norm(ApplyHomography(*S, from[k]) - to[k]));
    return Median(d);
  };
  if (nav.size() < 2) return;
  // The edges' residuals are in pixels, unweighted, as if a matched pixel were off by 1 px; it is
  // off by what the kept edges leave (~0.2 px a coordinate). The navigation's sigma is put in the
  // same units, or it would weigh tens of times more than it should against vision, and its noise
  // would bend a map of thousands of frames.
  const double pixel_sigma = std::max(0.05, KeptEdgesRms(g, s) / std::sqrt(2.0));
  cv::Matx33d to_map;
  summary->navigation_before_m = residual(&to_map);
  for (int round = 0; round < 2 && summary->navigation_before_m >= 0; ++round) {
    const cv::Matx33d from_map = to_map.inv();
    const double metres_per_px = std::sqrt(std::abs(to_map(0, 0) * to_map(1, 1) - to_map(0, 1) * to_map(1, 0)));
    std::vector<GroundPrior> priors;
    for (const auto& n : nav) {
      GroundPrior p;
      p.frame = n.node;
      p.pixel = n.pixel;
      p.xy = ApplyHomography(from_map, n.map);
      p.sigma_px = o.navigation_sigma_m / std::max(1e-12, metres_per_px) / pixel_sigma;
      priors.push_back(p);
    }
    summary->edges_dropped += AdjustParts(g, s, priors, o, pfo);
    summary->navigation_after_m = residual(&to_map);
  }
}

// Stage 8: parts side by side (largest first, left to right), each frame's placement, residual
// and uncertainty, each patch's best-fit placement and part; the store changed in one step.
void WriteAlignment(Store& store, FrameGraph& g, const GraphSolution& s, const std::vector<int>& followed_node,
                    const std::vector<FrameConfidence>& confidence, AlignSummary* summary) {
  const cv::Size frame = g.frame;
  std::map<int, int> extra_frames;  // root -> followed frames in its part
  UnionFind comp(static_cast<size_t>(g.size()));
  std::map<int, int> root_of;
  for (const auto& [root, list] : s.members)
    for (int i : list) root_of[i] = root;
  for (int i : followed_node)
    if (i >= 0) ++extra_frames[root_of[i]];
  std::vector<std::pair<int, int>> by_size;  // (frames, root)
  for (const auto& [root, list] : s.members) by_size.emplace_back(static_cast<int>(list.size()) + extra_frames[root], root);
  std::sort(by_size.begin(), by_size.end(), [](const auto& x, const auto& y) {
    return x.first != y.first ? x.first > y.first : x.second < y.second;
  });
  std::map<int, int> component_of_root;
  std::map<int, cv::Matx33d> shift;  // root -> plane to global
  double next_x = 0;
  for (size_t c = 0; c < by_size.size(); ++c) {
    const int root = by_size[c].second;
    component_of_root[root] = static_cast<int>(c);
    summary->component_frames.push_back(by_size[c].first);
    cv::Rect2d box;
    for (int i : s.members.at(root)) {
      const cv::Rect2d b = WarpedBounds(NodeToPlane(g, s, i), frame);
      box = box.area() > 0 ? (box | b) : b;
    }
    // The largest part keeps its coordinates (navigation, if any, fitted to it); the others follow
    // to its right, a frame's width apart.
    if (c == 0) {
      shift[root] = cv::Matx33d::eye();
      next_x = box.x + box.width + frame.width;
    } else {
      shift[root] = cv::Matx33d(1, 0, next_x - box.x, 0, 1, -box.y, 0, 0, 1);
      next_x += box.width + frame.width;
    }
  }
  summary->components = static_cast<int>(by_size.size());
  std::map<int, std::vector<cv::Point2d>> patch_pts, global_pts;
  std::map<int, std::map<int, int>> patch_components;
  for (int i = 0; i < g.size(); ++i) {
    const GraphNode& n = g.nodes[size_t(i)];
    const int root = root_of[i];
    const cv::Matx33d to_global = shift[root] * NodeToPlane(g, s, i);
    PatchSidecar& side = g.sidecars[n.patch];
    FrameRecord& rec = side.frames[n.record];
    rec.frame_to_global = ToArray9(to_global);
    confidence[size_t(i)].WriteTo(&rec);
    ++patch_components[n.patch][component_of_root[root]];
    for (int gy = 0; gy < 3; ++gy)
      for (int gx = 0; gx < 3; ++gx) {
        const cv::Point2d p(gx * (frame.width - 1) / 2.0, gy * (frame.height - 1) / 2.0);
        patch_pts[n.patch].push_back(ApplyHomography(n.to_patch, p));
        global_pts[n.patch].push_back(ApplyHomography(to_global, p));
      }
  }
  for (size_t k = 0; k < g.followed.size(); ++k) {
    const int i = followed_node[k];
    if (i < 0) continue;
    const GraphNode& key = g.nodes[size_t(i)];
    PatchSidecar& side = g.sidecars[g.followed[k].patch];
    FrameRecord& f = side.frames[g.followed[k].record];
    const cv::Matx33d key_to_global = ToMatx(*g.sidecars[key.patch].frames[key.record].frame_to_global);
    f.frame_to_global = ToArray9(key_to_global * key.to_patch.inv() * ToMatx(f.frame_to_patch));
    confidence[size_t(i)].WriteTo(&f);  // as sure as the keyframe it goes with
  }
  std::vector<PatchSidecar> updated;
  for (auto& [id, side] : g.sidecars) {
    if (side.patch_to_global && !side.patch_to_global_online) side.patch_to_global_online = *side.patch_to_global;
    const cv::Mat H = cv::findHomography(patch_pts[id], global_pts[id], 0);
    if (H.empty()) Fail(store.PatchSidecarPath(id), "its frames give no patch placement");
    side.patch_to_global = ToArray9(cv::Matx33d(H));
    side.aligned = true;
    int best = 0, count = -1;
    for (const auto& [c, k] : patch_components[id])
      if (k > count) best = c, count = k;
    side.component = best;
    updated.push_back(side);
  }
  GlobalRecord global = store.global();
  store.ReplaceSidecars(updated, global);
}

}  // namespace

AlignSummary AlignStore(Store store, const AlignOptions& o, const ProgressFn& progress) {
  std::string error;
  if (!o.IsValid(&error)) Fail("align", error);
  // Align rewrites every sidecar and the manifest: a mosaic engine writing the store meanwhile
  // would list its patches under the sidecars align removes. Refused while one writes; the store
  // read again once the lock is held (an engine may have ended since it was opened).
  const auto lock = LockStoreForChange(store, "rolamos align");
  const auto start = std::chrono::steady_clock::now();
  auto report = [&](double f) {
    if (progress) progress(std::min(1.0, f));
  };
  AlignSummary summary;
  ParallelForOptions pfo;
  pfo.threads = o.threads;
  auto stage_start = start;
  auto lap = [&](const char* name) {
    const auto now = std::chrono::steady_clock::now();
    summary.stages.push_back({name, std::chrono::duration<double>(now - stage_start).count(), PeakRssMb()});
    stage_start = now;
  };

  // 1-3. The graph: frames, the engine's links, appearance retrieval.
  FrameGraph g = LoadFrameGraph(store, o, &summary, pfo);
  lap("graph");
  report(0.1);
  AddRetrievalEdges(g, o, &summary, pfo);
  AddRejoiningEdges(g, o, &summary, pfo);
  lap("retrieval");
  report(0.3);
  const std::vector<int> followed_node = FollowedNodes(g);
  const std::vector<NavPoint> nav = NavigationPoints(g, followed_node, o);
  if (!o.navigation.empty()) {
    summary.navigation_frames = static_cast<int>(nav.size());
    if (nav.empty())
      Fail("navigation", "none of its " + std::to_string(o.navigation.size()) +
                             " frames is a frame of this store (frames are matched by file name)");
  }

  // Appearance edges that contradict the engine's chain, the other appearance edges or the
  // navigation: out before any placement rests on them.
  std::vector<NavigationFix> fixes;
  for (const auto& p : nav) fixes.push_back({p.node, p.pixel, p.map});
  const ConsistencyReport consistency = CheckAppearanceEdges(g, o, fixes, pfo);
  summary.edges_inconsistent = consistency.dropped_edges;
  summary.rejected_joins = consistency.rejected;
  RemoveEdges(g, consistency.drop);
  lap("consistency");
  report(0.4);

  // 4-6. First placement, adjustment, loop closures.
  UnionFind comp(0);
  const std::vector<cv::Matx33d> G = PlaceFirst(g, &comp);
  GraphSolution first = StartSolution(g, G, comp);
  summary.rms_before_px = KeptEdgesRms(g, first);
  GraphSolution s = SolveGraph(g, std::move(first), comp, o, pfo, /*trust_chain=*/false, &summary);
  lap("solve");
  report(0.6);
  // A link of the engine's chain within a patch found false hundreds of pixels off is not a
  // noisy link but a group of frames pulled away by links that agree with each other and not
  // with the chain (a lane's start drawn at twice the scale on 10,000 frames). Solved again, the
  // chain first.
  summary.chain_break_px = WorstDroppedChainLink(g, s);
  if (summary.chain_break_px > o.chain_break_px) {
    RemoveLoopClosures(g);  // found again from the chain's placement
    summary.edges_dropped = summary.loop_edges = summary.loop_tried = 0;
    s = SolveGraph(g, StartSolution(g, G, comp), comp, o, pfo, /*trust_chain=*/true, &summary);
    lap("solve, chain first");
  }
  report(0.8);

  // 7. Navigation.
  FollowNavigation(g, s, nav, o, pfo, &summary);
  if (!nav.empty()) lap("navigation");
  summary.rms_after_px = KeptEdgesRms(g, s);

  // Where the map is sure and where it rests on little: each frame's residual and uncertainty;
  // frames far off their own edges are placed again from them, or flagged.
  std::vector<FrameConfidence> confidence = AssessFrames(g, s, o, &summary);
  lap("confidence");
  report(0.9);

  // 8. The store.
  WriteAlignment(store, g, s, followed_node, confidence, &summary);
  lap("store");
  report(1.0);
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos
