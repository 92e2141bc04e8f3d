#include "align/first_placement.h"

#include <algorithm>
#include <map>

#include <opencv2/calib3d.hpp>

#include "geometry/plane_camera.h"
#include "util/homography.h"

namespace rolamos {

namespace {

// Two patches joined by an edge: a similarity between their coordinates.
struct PatchEdge {
  int p = 0, q = 0;
  cv::Matx33d p_to_q;
  EdgeKind kind = kOnline;
  size_t inliers = 0;
};

// The strongest edge between each pair of patches, as a similarity: chained over hundreds of
// patches, a homography's projective terms would run away; level cameras need no more.
std::vector<PatchEdge> StrongestBetweenPatches(const FrameGraph& g, const std::vector<char>& usable) {
  std::map<std::pair<int, int>, PatchEdge> between;
  for (size_t k = 0; k < g.edges.size(); ++k) {
    if (!usable.empty() && !usable[k]) continue;
    const GraphEdge& e = g.edges[k];
    const GraphNode& a = g.nodes[size_t(e.a)];
    const GraphNode& b = g.nodes[size_t(e.b)];
    if (a.patch == b.patch) continue;
    std::vector<cv::Point2f> in_p, in_q;
    for (size_t i = 0; i < e.in_a.size(); ++i) {
      in_p.push_back(cv::Point2f(ApplyHomography(a.to_patch, e.in_a[i])));
      in_q.push_back(cv::Point2f(ApplyHomography(b.to_patch, e.in_b[i])));
    }
    const cv::Mat S = cv::estimateAffinePartial2D(in_p, in_q, cv::noArray(), cv::LMEDS);
    if (S.empty()) continue;
    const cv::Matx23d T(S);
    PatchEdge pe;
    pe.p = a.patch;
    pe.q = b.patch;
    pe.p_to_q = cv::Matx33d(T(0, 0), T(0, 1), T(0, 2), T(1, 0), T(1, 1), T(1, 2), 0, 0, 1);
    pe.kind = e.kind;
    pe.inliers = e.Matches();
    auto key = std::make_pair(std::min(pe.p, pe.q), std::max(pe.p, pe.q));
    if (pe.p > pe.q) {
      std::swap(pe.p, pe.q);
      pe.p_to_q = pe.p_to_q.inv();
    }
    auto it = between.find(key);
    if (it == between.end() ||
        std::make_pair(-int(pe.kind), pe.inliers) > std::make_pair(-int(it->second.kind), it->second.inliers))
      between[key] = pe;
  }
  std::vector<PatchEdge> order;
  for (const auto& [key, pe] : between) order.push_back(pe);
  std::stable_sort(order.begin(), order.end(), [](const PatchEdge& x, const PatchEdge& y) {
    return x.kind != y.kind ? x.kind < y.kind : x.inliers > y.inliers;
  });
  return order;
}

}  // namespace

std::vector<cv::Matx33d> PlaceFirst(const FrameGraph& g, UnionFind* comp, const std::vector<char>& usable) {
  const int N = g.size();
  *comp = UnionFind(static_cast<size_t>(N));
  for (size_t k = 0; k < g.edges.size(); ++k)
    if (usable.empty() || usable[k]) comp->Join(g.edges[k].a, g.edges[k].b);
  // The patches' spanning tree, then each patch placed from its tree neighbour.
  std::map<int, int> patch_slot;
  for (const auto& [id, s] : g.sidecars) patch_slot[id] = static_cast<int>(patch_slot.size());
  UnionFind patch_comp{patch_slot.size()};
  std::map<int, std::vector<std::pair<int, cv::Matx33d>>> patch_tree;  // patch -> (neighbour, this -> neighbour)
  for (const auto& pe : StrongestBetweenPatches(g, usable))
    if (patch_comp.Join(patch_slot[pe.p], patch_slot[pe.q])) {
      patch_tree[pe.p].emplace_back(pe.q, pe.p_to_q);
      patch_tree[pe.q].emplace_back(pe.p, pe.p_to_q.inv());
    }
  std::map<int, cv::Matx33d> patch_to_plane;
  for (const auto& [id, s] : g.sidecars) {
    if (patch_to_plane.count(id)) continue;
    patch_to_plane[id] = cv::Matx33d::eye();
    std::vector<int> queue{id};
    for (size_t k = 0; k < queue.size(); ++k) {
      const int u = queue[k];
      for (const auto& [v, u_to_v] : patch_tree[u]) {
        if (patch_to_plane.count(v)) continue;
        cv::Matx33d G = patch_to_plane[u] * u_to_v.inv();
        G *= 1.0 / G(2, 2);
        patch_to_plane[v] = G;
        queue.push_back(v);
      }
    }
  }
  std::vector<cv::Matx33d> G(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i) G[size_t(i)] = patch_to_plane[g.nodes[size_t(i)].patch] * g.nodes[size_t(i)].to_patch;
  // Each part's reference: the level camera over its root frame (its centre, heading and scale),
  // its pixels the plane's. Not the root frame itself: the patches' placements are over the
  // seafloor plane, and a root pitched by 6 degrees at 90 across would make its own image plane
  // the map's, whose horizon lies 4 frame widths away (a jittered survey's map folded there).
  std::map<int, std::vector<int>> members;
  for (int i = 0; i < N; ++i) members[comp->Find(i)].push_back(i);
  for (auto& [root, list] : members) {
    const cv::Matx33d level = FrameToPlane(LevelPoseFromHomography(G[size_t(root)], g.K, g.frame), g.K);
    const cv::Matx33d to_ref = level.inv();
    for (int i : list) {
      G[size_t(i)] = to_ref * G[size_t(i)];
      G[size_t(i)] *= 1.0 / G[size_t(i)](2, 2);
    }
  }
  return G;
}

}  // namespace rolamos
