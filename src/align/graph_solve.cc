#include "align/graph_solve.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <unordered_map>

#include "engine/registration.h"
#include "util/homography.h"

namespace rolamos {

PlaneLink LinkOf(const GraphEdge& e, int a, int b) {
  PlaneLink l;
  l.a = a;
  l.b = b;
  l.in_a = e.in_a;
  l.in_b = e.in_b;
  l.pair_weight = e.weight;
  l.scatter_px = e.scatter_px;
  return l;
}

double TypicalScatter(const FrameGraph& g) {
  std::vector<double> scatter;
  for (const auto& e : g.edges)
    if (e.scatter_px > 0) scatter.push_back(e.scatter_px);
  return scatter.empty() ? 0.0 : Median(std::move(scatter));
}

double ScatterWeight(const GraphEdge& e, double typical, double floor_px) {
  if (!(e.scatter_px > 0) || !(floor_px > 0) || !(typical > 0)) return 1.0;
  return typical / std::max(double(e.scatter_px), floor_px);
}

cv::Matx33d NodeToPlane(const FrameGraph& g, const GraphSolution& s, int i) { return FrameToPlane(s.poses[size_t(i)], g.K); }

void ScaleToTypicalFrame(const FrameGraph& g, GraphSolution& s) {
  const double reference = ReferencePose(g.K).centre[2];
  for (const auto& [root, list] : s.members) {
    std::vector<double> altitude;
    for (int i : list) altitude.push_back(s.poses[size_t(i)].centre[2]);
    const double typical = Median(altitude);
    if (!(typical < 0)) continue;
    const double k = reference / typical;
    for (int i : list) s.poses[size_t(i)].centre *= k;
  }
}

GraphSolution StartSolution(const FrameGraph& g, const std::vector<cv::Matx33d>& G, UnionFind& comp) {
  GraphSolution s;
  const int N = g.size();
  for (int i = 0; i < N; ++i) s.members[comp.Find(i)].push_back(i);
  std::vector<int> degree(static_cast<size_t>(N), 0);
  for (const auto& e : g.edges) ++degree[size_t(e.a)], ++degree[size_t(e.b)];
  for (const auto& [root, list] : s.members) {
    int best = root;
    for (int i : list)
      if (degree[size_t(i)] > degree[size_t(best)]) best = i;
    s.anchor[root] = best;
  }
  s.poses.resize(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i)
    s.poses[size_t(i)] = comp.Find(i) == i ? ReferencePose(g.K) : LevelPoseFromHomography(G[size_t(i)], g.K, g.frame);
  ScaleToTypicalFrame(g, s);
  s.dropped.assign(g.edges.size(), 0);
  return s;
}

int AdjustParts(const FrameGraph& g, GraphSolution& s, const std::vector<GroundPrior>& priors, const AlignOptions& o,
                const ParallelForOptions& pfo, AdjustMode mode) {
  PlaneAdjustmentOptions po;
  po.loss = "cauchy";
  po.loss_px = mode == AdjustMode::kWide ? 10 * o.loss_px : o.loss_px;
  po.per_link = true;
  po.drop_link_px = mode == AdjustMode::kJudge ? 3 * o.loss_px : 0;
  const bool trust_chain = mode == AdjustMode::kTrustChain;
  po.max_iterations = 200;
  s.dropped.resize(g.edges.size(), 0);
  std::vector<std::pair<int, std::vector<int>>> parts(s.members.begin(), s.members.end());
  std::atomic<int> dropped_count{0};
  const double typical_scatter = TypicalScatter(g);
  // Parts in parallel; one part (the usual survey) gets every thread inside its solver.
  const int solver_threads = parts.size() == 1 ? ParallelThreads(pfo.threads) : 1;
  ParallelFor(static_cast<long long>(parts.size()), [&](long long c, int) {
    const auto& [root, list] = parts[size_t(c)];
    if (list.size() < 2) return;
    std::map<int, int> local;
    std::vector<PlanePose> part;
    for (int i : list) {
      local[i] = static_cast<int>(part.size());
      part.push_back(s.poses[size_t(i)]);
    }
    std::vector<PlaneLink> links;
    std::vector<size_t> which;
    for (size_t k = 0; k < g.edges.size(); ++k) {
      if (s.dropped[k] || !local.count(g.edges[k].a)) continue;
      PlaneLink l = LinkOf(g.edges[k], local[g.edges[k].a], local[g.edges[k].b]);
      l.weight = ScatterWeight(g.edges[k], typical_scatter, o.scatter_floor_px);
      l.trusted = trust_chain && g.edges[k].kind == kOnline;
      links.push_back(std::move(l));
      which.push_back(k);
    }
    std::vector<GroundPrior> mine;
    for (const auto& p : priors)
      if (local.count(p.frame)) {
        GroundPrior q = p;
        q.frame = local[p.frame];
        mine.push_back(q);
      }
    PlaneAdjustmentOptions opt = po;
    opt.threads = solver_threads;
    double f = g.focal;
    const PlaneAdjustment r = AdjustPlanePoses(&part, &f, g.frame, links, local[s.anchor.at(root)], {},
                                               mine.size() >= 2 ? mine : std::vector<GroundPrior>{}, opt);
    if (!r.ok) return;  // the placement it had stays
    for (size_t k = 0; k < which.size(); ++k)
      if (r.dropped[k]) {
        s.dropped[which[k]] = 1;
        ++dropped_count;
      }
    for (int i : list) s.poses[size_t(i)] = part[size_t(local[i])];
  }, pfo);
  return dropped_count.load();
}

double WorstDroppedChainLink(const FrameGraph& g, const GraphSolution& s) {
  double worst = 0;
  for (size_t k = 0; k < g.edges.size() && k < s.dropped.size(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (!s.dropped[k] || e.kind != kOnline || g.nodes[size_t(e.a)].patch != g.nodes[size_t(e.b)].patch) continue;
    worst = std::max(worst, PlaneTransferRms(s.poses, g.focal, g.frame, {LinkOf(e, e.a, e.b)}));
  }
  return worst;
}

double KeptEdgesRms(const FrameGraph& g, const GraphSolution& s) {
  std::vector<PlaneLink> all;
  for (size_t k = 0; k < g.edges.size(); ++k) {
    if (k < s.dropped.size() && s.dropped[k]) continue;
    all.push_back(LinkOf(g.edges[k], g.edges[k].a, g.edges[k].b));
  }
  return PlaneTransferRms(s.poses, g.focal, g.frame, all);
}

int AddLoopClosures(FrameGraph& g, GraphSolution& s, UnionFind& comp, const AlignOptions& o, AlignSummary* summary,
                    const ParallelForOptions& pfo) {
  const int N = g.size();
  const cv::Size frame = g.frame;
  std::vector<cv::Matx33d> P(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i) P[size_t(i)] = NodeToPlane(g, s, i);
  // Pairs whose footprints' bounds share a cell of a grid as fine as the median footprint: a
  // part of the map drawn at another scale (a drifted chain) is searched as well as the rest.
  std::vector<cv::Rect2d> bounds(static_cast<size_t>(N));
  std::vector<double> sizes;
  for (int i = 0; i < N; ++i) {
    bounds[size_t(i)] = WarpedBounds(P[size_t(i)], frame);
    sizes.push_back(std::max(bounds[size_t(i)].width, bounds[size_t(i)].height));
  }
  const double cell = std::max(1.0, Median(sizes));
  auto key = [&](long long cx, long long cy) { return (cx << 32) ^ static_cast<long long>(uint32_t(int32_t(cy))); };
  auto cells = [&](int i, const std::function<void(int64_t)>& f) {
    const cv::Rect2d& r = bounds[size_t(i)];
    if (!std::isfinite(r.x) || !std::isfinite(r.y) || !std::isfinite(r.width) || !std::isfinite(r.height)) return;
    const long long x0 = (long long)std::floor(r.x / cell), x1 = (long long)std::floor((r.x + r.width) / cell);
    const long long y0 = (long long)std::floor(r.y / cell), y1 = (long long)std::floor((r.y + r.height) / cell);
    if ((x1 - x0 + 1) * (y1 - y0 + 1) > 256) return;  // a footprint blown up by a wild placement: not searched
    for (long long cy = y0; cy <= y1; ++cy)
      for (long long cx = x0; cx <= x1; ++cx) f(key(cx, cy));
  };
  std::unordered_map<int64_t, std::vector<int>> grid;
  for (int i = 0; i < N; ++i) cells(i, [&](int64_t k) { grid[k].push_back(i); });
  std::vector<std::pair<int, int>> candidates;
  for (int i = 0; i < N; ++i) {
    std::vector<int> seen;
    cells(i, [&](int64_t k) {
      auto it = grid.find(k);
      if (it != grid.end()) seen.insert(seen.end(), it->second.begin(), it->second.end());
    });
    std::sort(seen.begin(), seen.end());
    seen.erase(std::unique(seen.begin(), seen.end()), seen.end());
    std::vector<std::pair<double, int>> near;
    for (int j : seen) {
      if (j <= i || comp.Find(i) != comp.Find(j) || g.NearInSequence(i, j, o.min_index_gap) || g.Linked(i, j)) continue;
      const double overlap = FootprintOverlap(P[size_t(i)], P[size_t(j)], frame);
      if (overlap >= o.loop_overlap) near.emplace_back(overlap, j);
    }
    std::sort(near.rbegin(), near.rend());
    for (size_t k = 0; k < near.size() && k < size_t(o.loops_per_frame); ++k) candidates.emplace_back(i, near[k].second);
  }
  summary->loop_tried += static_cast<int>(candidates.size());
  std::vector<GraphEdge> found(candidates.size());
  std::vector<char> ok(candidates.size(), 0);
  ParallelFor(static_cast<long long>(candidates.size()), [&](long long k, int) {
    const auto [i, j] = candidates[size_t(k)];
    const cv::Matx33d guess = P[size_t(j)].inv() * P[size_t(i)];
    GraphEdge e;
    if (!VerifyPair(g.nodes[size_t(i)], g.nodes[size_t(j)], &guess, frame, o, &e)) return;
    e.a = i;
    e.b = j;
    e.kind = kLoop;
    found[size_t(k)] = MeasureEdge(std::move(e), o, frame);
    ok[size_t(k)] = 1;
  }, pfo);
  int added = 0;
  for (size_t k = 0; k < found.size(); ++k)
    if (ok[k]) {
      g.AddLinked(found[k].a, found[k].b);
      g.edges.push_back(std::move(found[k]));
      s.dropped.push_back(0);
      ++added;
    }
  summary->loop_edges += added;
  return added;
}

// Loop closures under the solution, each round followed by an adjustment (`mode`): the first
// straighten the map and bring more neighbours into view. Rounds go on while a round finds more
// than a hundredth of the loop closures so far (a region held by its chain alone gets its
// closures once its neighbours have moved to it), at most `kMaxLoopRounds`.
void CloseLoops(FrameGraph& g, GraphSolution& s, UnionFind& comp, const AlignOptions& o, const ParallelForOptions& pfo,
                AdjustMode mode, AlignSummary* summary) {
  constexpr int kMaxLoopRounds = 4;
  for (int round = 0; round < kMaxLoopRounds && o.loops_per_frame > 0; ++round) {
    const int added = AddLoopClosures(g, s, comp, o, summary, pfo);
    if (added == 0) break;
    summary->edges_dropped += AdjustParts(g, s, {}, o, pfo, mode);
    if (round > 0 && added * 100 < summary->loop_edges) break;
  }
}

// 4-6. From the first placement `s` (StartSolution): the adjustment, then loop closures under it.
// With `trust_chain`, the engine's chain decides where groups of frames go: a group that other
// links pulled away comes back, and those links become the outliers.
GraphSolution SolveGraph(FrameGraph& g, GraphSolution s, UnionFind& comp, const AlignOptions& o,
                         const ParallelForOptions& pfo, bool trust_chain, AlignSummary* summary) {
  const AdjustMode mode = trust_chain ? AdjustMode::kTrustChain : AdjustMode::kJudge;
  summary->edges_dropped += AdjustParts(g, s, {}, o, pfo, mode);
  CloseLoops(g, s, comp, o, pfo, mode, summary);
  if (trust_chain) {
    // Then every link, the chain's too, judged from there: first with a wide loss, so that the
    // loop closures undo the chain's drift (tens of pixels at a lane's end) before any is judged
    // on its residual, then as usual; loop closures the straightened map brings into view last.
    AdjustParts(g, s, {}, o, pfo, AdjustMode::kWide);
    summary->edges_dropped += AdjustParts(g, s, {}, o, pfo, AdjustMode::kJudge);
    CloseLoops(g, s, comp, o, pfo, AdjustMode::kJudge, summary);
  }
  ScaleToTypicalFrame(g, s);
  return s;
}

void RemoveLoopClosures(FrameGraph& g) {
  std::vector<GraphEdge> kept;
  for (auto& e : g.edges) {
    if (e.kind == kLoop) g.linked.erase({std::min(e.a, e.b), std::max(e.a, e.b)});
    else kept.push_back(std::move(e));
  }
  g.edges = std::move(kept);
}

}  // namespace rolamos
