#include "align/frame_confidence.h"

#include <algorithm>
#include <cmath>
#include <map>

#include <opencv2/calib3d.hpp>

#include "util/homography.h"

namespace rolamos {

void FrameConfidence::WriteTo(FrameRecord* record) const {
  record->residual_px = residual_px;
  record->uncertainty_px = uncertainty_px;
  record->align_edges = edges;
  if (doubtful) record->placement_doubtful = true;
  else record->placement_doubtful.reset();
}

std::vector<double> GraphUncertainty(int n, const std::vector<std::pair<int, int>>& edges,
                                     const std::vector<double>& edge_residual, const std::vector<cv::Point2d>& centre,
                                     const std::vector<int>& anchor_of, double diag) {
  // The simple graph: one link per pair of frames, its error the worst of its edges'.
  std::map<std::pair<int, int>, double> pair_error;
  for (size_t k = 0; k < edges.size(); ++k) {
    auto [a, b] = edges[k];
    if (a == b) continue;
    auto key = std::make_pair(std::min(a, b), std::max(a, b));
    pair_error[key] = std::max(pair_error[key], edge_residual[k]);
  }
  std::vector<std::pair<int, int>> links;
  std::vector<double> link_error;
  std::vector<std::vector<std::pair<int, int>>> adj(static_cast<size_t>(n));  // (neighbour, link)
  for (const auto& [key, error] : pair_error) {
    adj[size_t(key.first)].push_back({key.second, int(links.size())});
    adj[size_t(key.second)].push_back({key.first, int(links.size())});
    links.push_back(key);
    link_error.push_back(error);
  }
  // Bridges (Tarjan's low-link, iteratively: long chains would overflow a recursion).
  std::vector<int> order(size_t(n), -1), low(size_t(n), 0);
  std::vector<char> bridge(links.size(), 0);
  int counter = 0;
  for (int s = 0; s < n; ++s) {
    if (order[size_t(s)] >= 0) continue;
    struct Frame { int node, via, next; };
    std::vector<Frame> stack{{s, -1, 0}};
    order[size_t(s)] = low[size_t(s)] = counter++;
    while (!stack.empty()) {
      Frame& f = stack.back();
      if (f.next < int(adj[size_t(f.node)].size())) {
        const auto [v, link] = adj[size_t(f.node)][size_t(f.next++)];
        if (link == f.via) continue;
        if (order[size_t(v)] < 0) {
          order[size_t(v)] = low[size_t(v)] = counter++;
          stack.push_back({v, link, 0});
        } else {
          low[size_t(f.node)] = std::min(low[size_t(f.node)], order[size_t(v)]);
        }
      } else {
        const Frame done = f;
        stack.pop_back();
        if (!stack.empty()) {
          Frame& parent = stack.back();
          low[size_t(parent.node)] = std::min(low[size_t(parent.node)], low[size_t(done.node)]);
          if (low[size_t(done.node)] > order[size_t(parent.node)]) bridge[size_t(done.via)] = 1;
        }
      }
    }
  }
  // From each part's anchor outwards: the bridges crossed on the way to every frame, as a shared
  // list (path entry: the bridge's far frame, its error, the entry before).
  struct Entry {
    int far = 0;
    double error = 0;
    int previous = -1;
  };
  std::vector<Entry> entries;
  std::vector<int> path(size_t(n), -2);  // -2: not reached; -1: no bridge crossed
  for (int s = 0; s < n; ++s) {
    const int a = anchor_of[size_t(s)];
    if (a < 0 || path[size_t(a)] != -2) continue;
    std::vector<int> queue{a};
    path[size_t(a)] = -1;
    for (size_t q = 0; q < queue.size(); ++q) {
      const int u = queue[q];
      for (const auto& [v, link] : adj[size_t(u)]) {
        if (path[size_t(v)] != -2) continue;
        if (bridge[size_t(link)]) {
          entries.push_back({v, std::max(0.5, link_error[size_t(link)]), path[size_t(u)]});
          path[size_t(v)] = int(entries.size()) - 1;
        } else {
          path[size_t(v)] = path[size_t(u)];
        }
        queue.push_back(v);
      }
    }
  }
  std::vector<double> out(size_t(n), 0);
  for (int i = 0; i < n; ++i) {
    double sum = 0;
    for (int e = path[size_t(i)]; e >= 0; e = entries[size_t(e)].previous) {
      const double lever = 1 + cv::norm(centre[size_t(i)] - centre[size_t(entries[size_t(e)].far)]) / diag;
      sum += std::pow(entries[size_t(e)].error * lever, 2);
    }
    out[size_t(i)] = std::sqrt(sum);
  }
  return out;
}

namespace {

// The RMS transfer error of edges' matched pixels through the solution (a compressed edge's
// scatter included, as PlaneTransferRms counts it).
double ResidualOf(const FrameGraph& g, const GraphSolution& s, const std::vector<size_t>& edges) {
  std::vector<PlaneLink> links;
  for (size_t k : edges) links.push_back(LinkOf(g.edges[k], g.edges[k].a, g.edges[k].b));
  return PlaneTransferRms(s.poses, g.focal, g.frame, links);
}

// A frame placed again from its own edges, its neighbours held: the homography that takes its
// matched pixels where the neighbours' placements put their partners. False when it does not fit.
bool PlaceAgain(const FrameGraph& g, GraphSolution& s, int i, const std::vector<size_t>& edges, double* residual) {
  std::vector<cv::Point2f> mine, plane;
  for (size_t k : edges) {
    const GraphEdge& e = g.edges[k];
    const bool a = e.a == i;
    const cv::Matx33d other = NodeToPlane(g, s, a ? e.b : e.a);
    for (size_t p = 0; p < e.in_a.size(); ++p) {
      mine.push_back(a ? e.in_a[p] : e.in_b[p]);
      plane.push_back(cv::Point2f(ApplyHomography(other, a ? e.in_b[p] : e.in_a[p])));
    }
  }
  if (mine.size() < 5) return false;
  std::vector<uchar> inlier;
  const cv::Mat H = cv::findHomography(mine, plane, cv::RANSAC, 3.0, inlier);
  if (H.empty()) return false;
  const PlanePose before = s.poses[size_t(i)];
  s.poses[size_t(i)] = LevelPoseFromHomography(cv::Matx33d(H), g.K, g.frame);
  const double after = ResidualOf(g, s, edges);
  if (!(after < *residual)) {
    s.poses[size_t(i)] = before;
    return false;
  }
  *residual = after;
  return true;
}

}  // namespace

std::vector<FrameConfidence> AssessFrames(const FrameGraph& g, GraphSolution& s, const AlignOptions& o,
                                          AlignSummary* summary) {
  const int n = g.size();
  std::vector<FrameConfidence> out(static_cast<size_t>(n));
  std::vector<std::vector<size_t>> edges_of(static_cast<size_t>(n));
  for (size_t k = 0; k < g.edges.size(); ++k) {
    if (k < s.dropped.size() && s.dropped[k]) continue;
    edges_of[size_t(g.edges[k].a)].push_back(k);
    edges_of[size_t(g.edges[k].b)].push_back(k);
  }
  auto residual_of = [&](int i) { return ResidualOf(g, s, edges_of[size_t(i)]); };
  std::vector<double> all;
  for (int i = 0; i < n; ++i) {
    out[size_t(i)].edges = static_cast<int>(edges_of[size_t(i)].size());
    out[size_t(i)].residual_px = residual_of(i);
    if (out[size_t(i)].edges > 0) all.push_back(out[size_t(i)].residual_px);
  }
  // Frames far off their own edges: placed again, or flagged.
  const double typical = Median(all);
  const double far = std::max(o.frame_residual_px, 5 * typical);
  for (int i = 0; i < n; ++i) {
    FrameConfidence& c = out[size_t(i)];
    if (c.edges > 0 && c.residual_px <= far) continue;
    if (c.edges > 0 && PlaceAgain(g, s, i, edges_of[size_t(i)], &c.residual_px)) {
      c.replaced = true;
      ++summary->frames_replaced;
    }
    if (c.edges == 0 || c.residual_px > far) {
      c.doubtful = true;
      ++summary->frames_doubtful;
    }
  }
  // The uncertainty: the graph's bridges and levers, then each frame's own share.
  std::vector<std::pair<int, int>> pairs;
  std::vector<double> pair_residual;
  for (size_t k = 0; k < g.edges.size(); ++k) {
    if (k < s.dropped.size() && s.dropped[k]) continue;
    pairs.push_back({g.edges[k].a, g.edges[k].b});
    pair_residual.push_back(ResidualOf(g, s, {k}));
  }
  std::vector<cv::Point2d> centre(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    centre[size_t(i)] = ApplyHomography(NodeToPlane(g, s, i), {g.frame.width / 2.0, g.frame.height / 2.0});
  std::vector<int> anchor_of(static_cast<size_t>(n), -1);
  for (const auto& [root, list] : s.members)
    for (int i : list) anchor_of[size_t(i)] = s.anchor.at(root);
  const std::vector<double> held =
      GraphUncertainty(n, pairs, pair_residual, centre, anchor_of, std::hypot(g.frame.width, g.frame.height));
  std::vector<double> u;
  for (int i = 0; i < n; ++i) {
    FrameConfidence& c = out[size_t(i)];
    const double own = std::max(0.1, c.residual_px) / std::sqrt(std::max(1, c.edges));
    c.uncertainty_px = std::sqrt(held[size_t(i)] * held[size_t(i)] + own * own);
    if (c.doubtful) c.uncertainty_px = std::max(c.uncertainty_px, far);
    u.push_back(c.uncertainty_px);
  }
  // The regions the map is unsure of: frames well above the map's typical uncertainty, by patch.
  const double limit = std::max(o.doubtful_px, 5 * Median(u));
  std::map<int, std::vector<int>> unsure;
  for (int i = 0; i < n; ++i)
    if (out[size_t(i)].doubtful || out[size_t(i)].uncertainty_px > limit) unsure[g.nodes[size_t(i)].patch].push_back(i);
  std::vector<DoubtfulRegion> regions;
  for (const auto& [patch, list] : unsure) {
    DoubtfulRegion r;
    r.patch = patch;
    r.first_frame = g.nodes[size_t(list.front())].index;
    r.last_frame = g.nodes[size_t(list.front())].index;
    for (int i : list) {
      r.first_frame = std::min(r.first_frame, g.nodes[size_t(i)].index);
      r.last_frame = std::max(r.last_frame, g.nodes[size_t(i)].index);
      r.frames += 1;
      r.worst_uncertainty_px = std::max(r.worst_uncertainty_px, out[size_t(i)].uncertainty_px);
      r.doubtful_frames += out[size_t(i)].doubtful;
    }
    regions.push_back(r);
  }
  std::sort(regions.begin(), regions.end(),
            [](const DoubtfulRegion& a, const DoubtfulRegion& b) { return a.worst_uncertainty_px > b.worst_uncertainty_px; });
  summary->doubtful_regions = regions;
  summary->median_uncertainty_px = Median(u);
  return out;
}

}  // namespace rolamos
