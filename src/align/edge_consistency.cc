#include "align/edge_consistency.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <map>
#include <optional>

#include <opencv2/calib3d.hpp>

#include "align/first_placement.h"
#include "align/navigation_fit.h"
#include "engine/registration.h"
#include "util/homography.h"

namespace rolamos {

namespace {

// The homography an edge measures, frame a -> frame b.
cv::Matx33d Measured(const GraphEdge& e) {
  const cv::Mat H = cv::findHomography(e.in_a, e.in_b, cv::LMEDS);
  if (H.empty()) return cv::Matx33d::eye();
  cv::Matx33d M(H);
  return M * (1.0 / M(2, 2));
}

// How far two frame a -> frame b placements disagree: the largest distance between where they put
// frame a's corners and centre (pixels of b), and the angle between them (degrees).
void Disagreement(const cv::Matx33d& x, const cv::Matx33d& y, cv::Size frame, double* px, double* degrees) {
  *px = 0;
  const double w = frame.width, h = frame.height;
  for (const cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(w, 0), cv::Point2d(0, h), cv::Point2d(w, h), cv::Point2d(w / 2, h / 2)})
    *px = std::max(*px, cv::norm(ApplyHomography(x, p) - ApplyHomography(y, p)));
  auto angle = [&](const cv::Matx33d& H) {
    const cv::Point2d c = ApplyHomography(H, {w / 2, h / 2}), e = ApplyHomography(H, {w / 2 + 100, h / 2});
    return std::atan2(e.y - c.y, e.x - c.x);
  };
  double d = std::abs(angle(x) - angle(y));
  d = std::fmod(d, 2 * CV_PI);
  *degrees = std::min(d, 2 * CV_PI - d) * 180 / CV_PI;
}

// "frames 120-135 (patch 4)": the frames on one side of a set of edges.
std::string FramesOf(const FrameGraph& g, const std::vector<int>& nodes) {
  if (nodes.empty()) return "no frames";
  std::map<int, std::pair<int, int>> by_patch;
  for (int i : nodes) {
    const GraphNode& n = g.nodes[size_t(i)];
    auto it = by_patch.find(n.patch);
    if (it == by_patch.end()) by_patch[n.patch] = {n.index, n.index};
    else it->second = {std::min(it->second.first, n.index), std::max(it->second.second, n.index)};
  }
  std::string out;
  for (const auto& [patch, range] : by_patch) {
    if (!out.empty()) out += ", ";
    out += "frames " + std::to_string(range.first) + (range.second > range.first ? "-" + std::to_string(range.second) : "") +
           " (patch " + std::to_string(patch) + ")";
  }
  return out;
}

RejectedJoin Rejected(const FrameGraph& g, const std::vector<size_t>& edges, const std::string& reason) {
  RejectedJoin r;
  r.reason = reason;
  r.edges = static_cast<int>(edges.size());
  std::vector<int> a, b;
  for (size_t k : edges) a.push_back(g.edges[k].a), b.push_back(g.edges[k].b);
  r.joined = FramesOf(g, a) + " with " + FramesOf(g, b);
  return r;
}

// Within one part of the chain: each appearance edge against the chain's placement.
void CheckAgainstChain(const FrameGraph& g, const AlignOptions& o, const std::vector<cv::Matx33d>& chain,
                       UnionFind& parts, ConsistencyReport* report) {
  const double diag = std::hypot(g.frame.width, g.frame.height);
  // Groups of dropped edges by the pair of patches they join, for the report.
  std::map<std::pair<int, int>, std::vector<size_t>> dropped;
  for (size_t k = 0; k < g.edges.size(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (e.kind == kOnline || parts.Find(e.a) != parts.Find(e.b)) continue;
    const cv::Matx33d predicted = chain[size_t(e.b)].inv() * chain[size_t(e.a)];
    double px = 0, degrees = 0;
    Disagreement(Measured(e), predicted, g.frame, &px, &degrees);
    // Drift grows with the chain between the two frames (the sequence is the chain's order).
    const double gap = std::abs(g.nodes[size_t(e.a)].index - g.nodes[size_t(e.b)].index);
    const double allowed_px = diag * (o.chain_tolerance + o.chain_drift * gap);
    const double allowed_degrees = 20 + 0.005 * gap;
    if (px <= allowed_px && degrees <= allowed_degrees) continue;
    report->drop[k] = 1;
    ++report->dropped_edges;
    const int pa = g.nodes[size_t(e.a)].patch, pb = g.nodes[size_t(e.b)].patch;
    dropped[{std::min(pa, pb), std::max(pa, pb)}].push_back(k);
  }
  for (const auto& [pair, list] : dropped)
    report->rejected.push_back(Rejected(g, list, "contradicts the engine's chain between them"));
}

// A set of edges between two parts of the chain that agree on where one part lies on the other.
struct JoinSet {
  std::vector<size_t> edges;
  cv::Matx33d a_to_b;  // part a's plane -> part b's plane
  double verified = -1;  // share of the overlap it implies that matched (-1: not testable)
  double nav_px = -1;    // disagreement with the navigation, pixels (-1: no navigation)
};

// Part a's plane -> part b's plane as one edge implies it.
cv::Matx33d Implied(const GraphEdge& e, const std::vector<cv::Matx33d>& chain) {
  cv::Matx33d T = chain[size_t(e.b)] * Measured(e) * chain[size_t(e.a)].inv();
  return T * (1.0 / T(2, 2));
}

// The consequence of a join: placed so, the parts overlap; where they overlap heavily (pairs of
// frames over the same ground by more than half), their frames must match. Side-by-side lanes
// overlap little and are not judged so (no such pairs: -1); a false join stacks ground on ground.
double VerifyOverlap(const FrameGraph& g, const AlignOptions& o, const std::vector<cv::Matx33d>& chain,
                     const std::vector<int>& in_a, const std::vector<int>& in_b, const JoinSet& set,
                     const ParallelForOptions& pfo) {
  std::vector<char> used(size_t(g.size()), 0);
  for (size_t k : set.edges) used[size_t(g.edges[k].a)] = used[size_t(g.edges[k].b)] = 1;
  // Pairs the join puts over the same ground, away from the frames that made it.
  std::vector<std::pair<double, std::pair<int, int>>> pairs;
  for (int i : in_a) {
    if (used[size_t(i)]) continue;
    const cv::Matx33d ia = set.a_to_b * chain[size_t(i)];
    for (int j : in_b) {
      if (used[size_t(j)] || g.Linked(i, j)) continue;
      const double overlap = FootprintOverlap(ia, chain[size_t(j)], g.frame);
      if (overlap >= 0.6) pairs.push_back({overlap, {i, j}});
    }
  }
  if (pairs.size() < 6) return -1;  // too little else to test
  std::sort(pairs.rbegin(), pairs.rend());
  // Spread over the overlap: every k-th of the best pairs, 16 at most.
  std::vector<std::pair<int, int>> tried;
  const size_t step = std::max<size_t>(1, pairs.size() / 16);
  for (size_t k = 0; k < pairs.size() && tried.size() < 16; k += step) tried.push_back(pairs[k].second);
  std::atomic<int> matched{0};
  ParallelFor(static_cast<long long>(tried.size()), [&](long long k, int) {
    const auto [i, j] = tried[size_t(k)];
    const cv::Matx33d guess = chain[size_t(j)].inv() * set.a_to_b * chain[size_t(i)];
    GraphEdge e;
    if (VerifyPair(g.nodes[size_t(i)], g.nodes[size_t(j)], &guess, g.frame, o, &e)) ++matched;
  }, pfo);
  return double(matched) / double(tried.size());
}

// Between two parts of the chain: the edges grouped into sets that agree, one set kept.
void CheckBetweenParts(const FrameGraph& g, const AlignOptions& o, const std::vector<cv::Matx33d>& chain,
                       UnionFind& parts, const std::vector<NavigationFix>& nav, const ParallelForOptions& pfo,
                       ConsistencyReport* report) {
  const double diag = std::hypot(g.frame.width, g.frame.height);
  std::map<std::pair<int, int>, std::vector<size_t>> by_pair;  // (part a, part b), a < b
  for (size_t k = 0; k < g.edges.size(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (e.kind == kOnline || report->drop[k]) continue;
    const int pa = parts.Find(e.a), pb = parts.Find(e.b);
    if (pa != pb) by_pair[{std::min(pa, pb), std::max(pa, pb)}].push_back(k);
  }
  if (by_pair.empty()) return;
  std::map<int, std::vector<int>> members;
  for (int i = 0; i < g.size(); ++i) members[parts.Find(i)].push_back(i);
  // Each part's plane -> the map, where it has navigation.
  std::map<int, std::vector<std::pair<cv::Point2d, cv::Point2d>>> fixes;
  for (const auto& f : nav) fixes[parts.Find(f.node)].push_back({ApplyHomography(chain[size_t(f.node)], f.pixel), f.map});
  auto to_map = [&](int part) -> std::optional<cv::Matx33d> {
    auto it = fixes.find(part);
    if (it == fixes.end() || it->second.size() < 2) return std::nullopt;
    std::vector<cv::Point2d> from, to;
    for (const auto& [p, m] : it->second) from.push_back(p), to.push_back(m);
    return FitSimilarity(from, to);
  };
  for (const auto& [pair, list] : by_pair) {
    const int pa = pair.first, pb = pair.second;
    // Every edge as part a -> part b (an edge the other way round inverted).
    std::vector<cv::Matx33d> implied;
    for (size_t k : list) {
      const GraphEdge& e = g.edges[k];
      const cv::Matx33d T = Implied(e, chain);
      implied.push_back(parts.Find(e.a) == pa ? T : cv::Matx33d(T.inv()));
    }
    // Where an edge puts part a's frames of the set, compared between edges.
    cv::Point2d centre(0, 0);
    for (size_t k : list) {
      const GraphEdge& e = g.edges[k];
      const int i = parts.Find(e.a) == pa ? e.a : e.b;
      centre += ApplyHomography(chain[size_t(i)], {g.frame.width / 2.0, g.frame.height / 2.0}) * (1.0 / double(list.size()));
    }
    const std::vector<cv::Point2d> probe = {centre, centre + cv::Point2d(diag, 0), centre + cv::Point2d(0, diag)};
    auto agree = [&](size_t x, size_t y) {
      for (const auto& p : probe)
        if (cv::norm(ApplyHomography(implied[x], p) - ApplyHomography(implied[y], p)) > o.chain_tolerance * diag) return false;
      return true;
    };
    // Sets: the edge most others agree with and those, then the next among the rest.
    std::vector<char> taken(list.size(), 0);
    std::vector<JoinSet> sets;
    for (;;) {
      int best = -1, support = 0;
      for (size_t x = 0; x < list.size(); ++x) {
        if (taken[x]) continue;
        int n = 0;
        for (size_t y = 0; y < list.size(); ++y) n += !taken[y] && agree(x, y);
        if (n > support) best = static_cast<int>(x), support = n;
      }
      if (best < 0) break;
      JoinSet set;
      set.a_to_b = implied[size_t(best)];
      for (size_t y = 0; y < list.size(); ++y)
        if (!taken[y] && agree(size_t(best), y)) {
          taken[y] = 1;
          set.edges.push_back(list[y]);
        }
      sets.push_back(std::move(set));
    }
    // Each set judged: by the navigation when both parts have it, else by its consequence.
    const auto ma = to_map(pa), mb = to_map(pb);
    for (auto& set : sets) {
      if (ma && mb) {
        const cv::Matx33d nav_a_to_b = mb->inv() * *ma;
        double worst = 0;
        for (const auto& p : probe) worst = std::max(worst, cv::norm(ApplyHomography(set.a_to_b, p) - ApplyHomography(nav_a_to_b, p)));
        set.nav_px = worst;
      } else if (set.edges.size() >= 3 || sets.size() > 1) {
        set.verified = VerifyOverlap(g, o, chain, members[pa], members[pb], set, pfo);
      }
    }
    // The winner: with navigation for both parts, the set closest to it (the navigation is the
    // arbiter); otherwise one whose overlap matched (or could not be tested), then the most edges.
    const bool navigated = ma && mb;
    auto score = [&](const JoinSet& s) {
      const double match = s.verified < 0 ? 0.5 : s.verified;
      return std::make_tuple(navigated ? -s.nav_px : 0.0, match >= 0.25 ? 1 : 0, s.edges.size());
    };
    size_t winner = 0;
    for (size_t k = 1; k < sets.size(); ++k)
      if (score(sets[k]) > score(sets[winner])) winner = k;
    for (size_t k = 0; k < sets.size(); ++k) {
      const JoinSet& s = sets[k];
      std::string reason;
      if (navigated && (k != winner || s.nav_px > 3 * diag)) {
        reason = "the navigation places these parts otherwise (" + std::to_string(int(s.nav_px)) + " px from it" +
                 (k != winner ? ", another set " + std::to_string(int(sets[winner].nav_px)) + " px)" : ")");
      } else if (s.verified >= 0 && s.verified < 0.25) {
        char b[160];
        std::snprintf(b, sizeof b, "placed so, the parts would overlap where their frames do not match (%.0f %% verified)",
                      100 * s.verified);
        reason = b;
      } else if (k != winner) {
        reason = "another set of " + std::to_string(sets[winner].edges.size()) + " edges places these parts otherwise";
      } else {
        continue;
      }
      for (size_t e : s.edges) report->drop[e] = 1;
      report->dropped_edges += static_cast<int>(s.edges.size());
      report->rejected.push_back(Rejected(g, s.edges, reason));
    }
  }
}

}  // namespace

ConsistencyReport CheckAppearanceEdges(const FrameGraph& g, const AlignOptions& o, const std::vector<NavigationFix>& nav,
                                       const ParallelForOptions& pfo) {
  ConsistencyReport report;
  report.drop.assign(g.edges.size(), 0);
  // The chain: the engine's links alone, placed as the first placement places them.
  std::vector<char> online(g.edges.size(), 0);
  for (size_t k = 0; k < g.edges.size(); ++k) online[k] = g.edges[k].kind == kOnline;
  UnionFind parts(0);
  const std::vector<cv::Matx33d> chain = PlaceFirst(g, &parts, online);
  CheckAgainstChain(g, o, chain, parts, &report);
  CheckBetweenParts(g, o, chain, parts, nav, pfo, &report);
  return report;
}

void RemoveEdges(FrameGraph& g, const std::vector<char>& drop) {
  std::vector<GraphEdge> kept;
  for (size_t k = 0; k < g.edges.size(); ++k)
    if (k >= drop.size() || !drop[k]) kept.push_back(std::move(g.edges[k]));
  g.edges = std::move(kept);
}

}  // namespace rolamos
