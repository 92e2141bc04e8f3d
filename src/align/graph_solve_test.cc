#include "align/graph_solve.h"

#include <functional>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>

#include "align/frame_graph.h"
#include "geometry/plane_camera.h"
#include "util/homography.h"

namespace rolamos {
namespace {

// An edge a -> b measured where `poses` put a grid of a's pixels (every `step` px from `first`)
// in b, those that land in b.
void AddMeasuredEdge(FrameGraph& g, const std::vector<PlanePose>& poses, int a, int b, EdgeKind kind,
                     cv::Point first, cv::Size step) {
  GraphEdge e;
  e.a = a;
  e.b = b;
  e.kind = kind;
  const cv::Matx33d H = PlaneToFrame(poses[size_t(b)], g.K) * FrameToPlane(poses[size_t(a)], g.K);
  for (int y = first.y; y < g.frame.height; y += step.height)
    for (int x = first.x; x < g.frame.width; x += step.width) {
      const cv::Vec3d q = H * cv::Vec3d(x, y, 1);
      const cv::Point2f in_b(float(q[0] / q[2]), float(q[1] / q[2]));
      if (in_b.x < 0 || in_b.y < 0 || in_b.x >= g.frame.width || in_b.y >= g.frame.height) continue;
      e.in_a.emplace_back(float(x), float(y));
      e.in_b.push_back(in_b);
    }
  g.edges.push_back(e);
  g.AddLinked(a, b);
}

// The tests' camera: 400 x 300 frames, a 400 px focal length.
void SetTestCamera(FrameGraph& g) {
  g.frame = cv::Size(400, 300);
  g.focal = 400;
  g.K = CameraMatrix(g.focal, g.frame);
}

// Three frames 150 px apart; edges from where `truth` puts a grid of a's pixels in b.
struct Line {
  FrameGraph g;
  std::vector<PlanePose> truth;
  Line() {
    SetTestCamera(g);
    for (int i = 0; i < 3; ++i) {
      GraphNode n;
      n.patch = i < 2 ? 1 : 2;  // frames 0 and 1 in patch 1, frame 2 in patch 2
      n.index = i;
      g.nodes.push_back(n);
      PlanePose p = ReferencePose(g.K);
      p.centre[0] += 150.0 * i;
      truth.push_back(p);
    }
  }
  void Add(int a, int b, EdgeKind kind) { AddMeasuredEdge(g, truth, a, b, kind, {200, 50}, {60, 100}); }
};

// Only a dropped engine link within one patch counts, by how far off the solution leaves it.
TEST(GraphSolve, WorstDroppedChainLinkIsTheChainWithinAPatch) {
  Line l;
  l.Add(0, 1, kOnline);  // within patch 1
  l.Add(1, 2, kOnline);  // across patches
  l.Add(0, 2, kLoop);
  GraphSolution s;
  s.poses = l.truth;
  s.poses[1].centre[0] += 40;  // frame 1 drawn 40 px off
  s.poses[2].centre[0] += 500;
  s.dropped.assign(l.g.edges.size(), 0);
  EXPECT_EQ(WorstDroppedChainLink(l.g, s), 0.0);  // nothing dropped
  s.dropped = {0, 1, 1};  // the join across patches and the loop: not the chain within a patch
  EXPECT_EQ(WorstDroppedChainLink(l.g, s), 0.0);
  s.dropped = {1, 1, 1};
  EXPECT_NEAR(WorstDroppedChainLink(l.g, s), 40.0, 2.0);
}

// Loop closures leave the graph and their pairs may be found again; the engine's links stay.
TEST(GraphSolve, RemoveLoopClosuresFreesTheirPairs) {
  Line l;
  l.Add(0, 1, kOnline);
  l.Add(2, 0, kLoop);
  l.Add(1, 2, kRetrieval);
  RemoveLoopClosures(l.g);
  ASSERT_EQ(l.g.edges.size(), 2u);
  EXPECT_EQ(l.g.edges[0].kind, kOnline);
  EXPECT_EQ(l.g.edges[1].kind, kRetrieval);
  EXPECT_FALSE(l.g.Linked(0, 2));
  EXPECT_TRUE(l.g.Linked(0, 1));
  EXPECT_TRUE(l.g.Linked(1, 2));
}

// A map whose gauge frame sat at a fifth of the others' altitude (a chain that drifted in scale)
// is drawn at the scale of its typical frame.
TEST(GraphSolve, TheMapIsDrawnAtTheScaleOfItsTypicalFrame) {
  Line l;
  GraphSolution s;
  s.poses = l.truth;
  for (auto& p : s.poses) p.centre *= 5.0;  // every frame five times higher than its gauge says
  s.members[0] = {0, 1, 2};
  ScaleToTypicalFrame(l.g, s);
  for (size_t i = 0; i < 3; ++i) {
    const cv::Rect2d b = WarpedBounds(FrameToPlane(s.poses[i], l.g.K), l.g.frame);
    EXPECT_NEAR(b.width, l.g.frame.width, 1e-6);
    EXPECT_NEAR(b.height, l.g.frame.height, 1e-6);
  }
  EXPECT_NEAR(s.poses[2].centre[0] - s.poses[0].centre[0], 300.0, 1e-6);  // the layout kept
}

// Loop closures are looked for among frames whose footprints meet, at whatever scale the
// solution draws them (five times the frames' own: a grid of one frame's pixels missed them).
TEST(GraphSolve, LoopClosuresAreSoughtAtTheScaleTheMapIsDrawnAt) {
  Line l;
  GraphSolution s;
  s.poses = l.truth;
  for (auto& p : s.poses) p.centre *= 5.0;
  s.members[0] = {0, 1, 2};
  s.dropped.clear();
  UnionFind comp(3);
  comp.Join(0, 1);
  comp.Join(1, 2);
  AlignOptions o;
  AlignSummary summary;
  AddLoopClosures(l.g, s, comp, o, &summary, {});
  // Frames 0 and 2 (1,500 map pixels apart, overlapping by a quarter) and 1 and 2; 0 and 1 are
  // neighbours in one patch, linked by the chain.
  EXPECT_EQ(summary.loop_tried, 2);
}

// Two lanes of 16 frames joined at one end (the turn), 33 % side overlap. The engine's chain along
// them drifts (each link turned 0.25 degrees: the far ends of the lanes 100 px apart where the
// truth has them side by side); loop closures between the lanes are true.
struct DriftingLanes {
  static constexpr int kLane = 16;
  FrameGraph g;
  std::vector<PlanePose> truth, chain;
  DriftingLanes() {
    g.frame = cv::Size(400, 300);
    g.focal = 400;
    g.K = CameraMatrix(g.focal, g.frame);
    for (int i = 0; i < 2 * kLane; ++i) {
      GraphNode n;
      n.patch = 1 + i / 4;
      n.index = i;
      g.nodes.push_back(n);
      PlanePose p = ReferencePose(g.K);
      const int along = i < kLane ? i : 2 * kLane - 1 - i;
      p.centre[0] += 100.0 * along;
      p.centre[1] += i < kLane ? 0 : 200;
      truth.push_back(p);
    }
    // The chain's placement: every step turned a little more.
    chain.push_back(truth[0]);
    for (int i = 1; i < 2 * kLane; ++i) {
      const double turn = 0.25 * CV_PI / 180 * i;
      const cv::Vec3d step = truth[size_t(i)].centre - truth[size_t(i - 1)].centre;
      PlanePose p = truth[size_t(i)];
      p.centre = chain.back().centre + cv::Vec3d(std::cos(turn) * step[0] - std::sin(turn) * step[1],
                                                 std::sin(turn) * step[0] + std::cos(turn) * step[1], step[2]);
      p.yaw = truth[size_t(i)].yaw + turn;
      chain.push_back(p);
    }
    for (int i = 1; i < 2 * kLane; ++i) Add(i - 1, i, kOnline, chain);
    for (int i = 0; i < kLane - 2; ++i) Add(i, 2 * kLane - 1 - i, kLoop, truth);
  }
  void Add(int a, int b, EdgeKind kind, const std::vector<PlanePose>& poses) {
    AddMeasuredEdge(g, poses, a, b, kind, {20, 20}, {40, 40});
  }
  // How far apart the solution puts the far ends of the two lanes, against the truth (px).
  double FarEndError(const GraphSolution& s) const {
    const cv::Vec3d solved = s.poses[0].centre - s.poses[size_t(2 * kLane - 1)].centre;
    const cv::Vec3d real = truth[0].centre - truth[size_t(2 * kLane - 1)].centre;
    return std::hypot(solved[0] - real[0], solved[1] - real[1]);
  }
};

// Solved with the chain first, the loop closures that disagree with the chain's drift by tens of
// pixels are true and stay: the lanes come back side by side. (Judged against the drifted chain
// they were dropped for good, and the lanes stayed splayed.)
TEST(GraphSolve, AChainFirstSolveKeepsTheLoopClosuresTheChainsDriftContradicts) {
  DriftingLanes l;
  UnionFind comp(l.g.nodes.size());
  for (const auto& e : l.g.edges) comp.Join(e.a, e.b);
  std::vector<cv::Matx33d> G;
  for (const auto& p : l.chain) G.push_back(FrameToPlane(p, l.g.K) * FrameToPlane(l.chain[0], l.g.K).inv());
  AlignOptions o;
  AlignSummary summary;
  const GraphSolution start = StartSolution(l.g, G, comp);
  GraphSolution chain_only = start;
  chain_only.poses = l.chain;
  ASSERT_GT(l.FarEndError(chain_only), 60.0);  // the drift the test is about
  const GraphSolution s = SolveGraph(l.g, start, comp, o, {}, /*trust_chain=*/true, &summary);
  EXPECT_EQ(summary.edges_dropped, 0);
  for (char d : s.dropped) EXPECT_FALSE(d);
  // The chain's links are biased by construction: the solution shares out their disagreement.
  EXPECT_LT(l.FarEndError(s), 0.1 * l.FarEndError(chain_only));
  EXPECT_LT(KeptEdgesRms(l.g, s), 1.0);
}

// Four lanes of twelve frames, each frame linked to its neighbours along and across the lanes by
// every 8th pixel's match, measured with 0.5 px of noise (or as given, along the lanes and
// across them): the map's shape is what the pairs' noise adds up to.
struct NoisyLanes {
  static constexpr int kLanes = 4, kPerLane = 12;
  FrameGraph full;
  std::vector<PlanePose> truth;
  explicit NoisyLanes(double along_px = 0.5, double across_px = 0.5) {
    SetTestCamera(full);
    for (int i = 0; i < kLanes * kPerLane; ++i) {
      GraphNode n;
      n.patch = 1 + i / kPerLane;
      n.index = i;
      full.nodes.push_back(n);
      PlanePose p = ReferencePose(full.K);
      p.centre[0] += 120.0 * (i % kPerLane);
      p.centre[1] += 180.0 * (i / kPerLane);
      truth.push_back(p);
    }
    cv::RNG rng(7);
    for (int a = 0; a < full.size(); ++a)
      for (int b = a + 1; b < full.size(); ++b) {
        const cv::Vec3d d = truth[size_t(b)].centre - truth[size_t(a)].centre;
        if (std::abs(d[0]) > 250 || std::abs(d[1]) > 200) continue;
        const size_t before = full.edges.size();
        AddMeasuredEdge(full, truth, a, b, d[1] == 0 ? kOnline : kLoop, {4, 4}, {8, 8});
        const double sigma = d[1] == 0 ? along_px : across_px;
        for (auto& q : full.edges[before].in_b) q += cv::Point2f(float(rng.gaussian(sigma)), float(rng.gaussian(sigma)));
      }
  }
  // The error of a solution: frame corners on its plane against the truth's, after the
  // homography that fits them best (the gauge).
  double Error(const GraphSolution& s) const {
    std::vector<cv::Point2f> ours, real;
    for (size_t i = 0; i < truth.size(); ++i)
      for (const cv::Point2d c : {cv::Point2d(0, 0), cv::Point2d(399, 0), cv::Point2d(0, 299), cv::Point2d(399, 299)}) {
        ours.emplace_back(ApplyHomography(FrameToPlane(s.poses[i], full.K), c));
        real.emplace_back(ApplyHomography(FrameToPlane(truth[i], full.K), c));
      }
    const cv::Matx33d H(cv::findHomography(ours, real, 0));
    double sum = 0;
    for (size_t k = 0; k < ours.size(); ++k) {
      const cv::Point2d e = ApplyHomography(H, cv::Point2d(ours[k])) - cv::Point2d(real[k]);
      sum += e.dot(e);
    }
    return std::sqrt(sum / double(ours.size()));
  }
  // The map from the edges as `measure` leaves them, from the true placement; its error.
  double Solve(const std::function<GraphEdge(GraphEdge)>& measure, FrameGraph* solved = nullptr,
               double scatter_floor_px = AlignOptions().scatter_floor_px) const {
    FrameGraph g = full;
    for (auto& e : g.edges) e = measure(std::move(e));
    UnionFind comp(g.nodes.size());
    for (const auto& e : g.edges) comp.Join(e.a, e.b);
    std::vector<cv::Matx33d> G;
    for (const auto& p : truth) G.push_back(FrameToPlane(p, g.K) * FrameToPlane(truth[0], g.K).inv());
    AlignOptions o;
    o.loops_per_frame = 0;  // the graph is all there is: the nodes have no features
    o.scatter_floor_px = scatter_floor_px;
    AlignSummary summary;
    const GraphSolution s = SolveGraph(g, StartSolution(g, G, comp), comp, o, {}, /*trust_chain=*/false, &summary);
    EXPECT_EQ(summary.edges_dropped, 0);
    if (solved) *solved = g;
    return Error(s);
  }
};

// The edges thinned to 60 pairs (ThinEdge, as align does with AlignOptions::pairs_per_edge) place
// the map closer to the truth than the same edges thinned to 6.
TEST(GraphSolve, MorePairsPerEdgeGiveATruerMap) {
  const NoisyLanes lanes;
  auto thinned = [&](int pairs) {
    FrameGraph g;
    const double px = lanes.Solve([&](GraphEdge e) { return ThinEdge(std::move(e), pairs, lanes.full.frame); }, &g);
    for (const auto& e : g.edges) EXPECT_LE(static_cast<int>(e.in_a.size()), pairs);
    return px;
  };
  const double few = thinned(6), many = thinned(60);
  RecordProperty("px_with_6_pairs", std::to_string(few));
  RecordProperty("px_with_60_pairs", std::to_string(many));
  EXPECT_GT(few, 0.02);  // the noise shows
  EXPECT_LT(many, 0.6 * few) << "6 pairs: " << few << " px, 60 pairs: " << many << " px";
}

// An edge compressed to the homography its 60 pairs fit, held at 9 weighted points, pulls the
// map as its 60 pairs do: the map is as true, from a seventh of the solver's rows; and what the
// solve reports of the edges (their residual over the matched pairs) still counts the pairs' noise.
TEST(GraphSolve, CompressedEdgesHoldTheMapAsTheirPairsDo) {
  const NoisyLanes lanes;
  const cv::Size frame = lanes.full.frame;
  const double pairs = lanes.Solve([&](GraphEdge e) { return ThinEdge(std::move(e), 60, frame); });
  const double few = lanes.Solve([&](GraphEdge e) { return ThinEdge(std::move(e), 9, frame); });
  FrameGraph g;
  const double compressed = lanes.Solve([&](GraphEdge e) { return CompressEdge(ThinEdge(std::move(e), 60, frame), 9); }, &g);
  RecordProperty("px_with_60_pairs", std::to_string(pairs));
  RecordProperty("px_compressed_to_9_points", std::to_string(compressed));
  RecordProperty("px_with_9_pairs", std::to_string(few));
  EXPECT_LT(compressed, 1.15 * pairs) << "60 pairs: " << pairs << " px, compressed: " << compressed << " px";
  EXPECT_LT(compressed, 0.75 * few) << "9 pairs: " << few << " px, compressed: " << compressed << " px";
  int compressed_edges = 0;
  for (const auto& e : g.edges) {
    EXPECT_LE(e.in_a.size(), 9u);
    if (e.weight.empty()) continue;
    ++compressed_edges;
    double count = 0;
    for (float w : e.weight) count += double(w) * w;
    EXPECT_NEAR(count, e.Matches(), 1e-3);
    // 0.5 px of noise in x and in y: 0.71 px a pair, less what the fit's 8 parameters take up.
    EXPECT_GT(e.scatter_px, 0.45);
    EXPECT_LT(e.scatter_px, 0.95);
  }
  EXPECT_GT(compressed_edges, int(g.edges.size()) / 2);
}

// Links followed to a tenth of a pixel along the lanes and matches a pixel off across them, each
// compressed as align does: weighed by their scatter, the precise links hold the lanes and the
// map is truer than with every edge weighed by its pairs alone; with the same noise everywhere
// the weights are all alike and the map the same.
TEST(GraphSolve, EdgesWeighByHowCloselyTheirPairsFit) {
  const auto compress = [](const NoisyLanes& lanes) {
    return [&lanes](GraphEdge e) { return CompressEdge(ThinEdge(std::move(e), 60, lanes.full.frame), 9); };
  };
  const NoisyLanes mixed(0.1, 1.0);
  FrameGraph g;
  const double weighed = mixed.Solve(compress(mixed), &g, 0.1), by_pairs = mixed.Solve(compress(mixed), nullptr, 0.0);
  RecordProperty("px_weighed_by_scatter", std::to_string(weighed));
  RecordProperty("px_by_pairs_alone", std::to_string(by_pairs));
  EXPECT_LT(weighed, 0.8 * by_pairs) << "weighed: " << weighed << " px, by pairs alone: " << by_pairs << " px";
  const double typical = TypicalScatter(g);
  for (const auto& e : g.edges) {
    const double w = ScatterWeight(e, typical, 0.1);
    if (e.kind == kOnline) EXPECT_GT(w, 2.0);
    else EXPECT_LT(w, 1.5);
  }
  const NoisyLanes even;
  EXPECT_NEAR(even.Solve(compress(even), nullptr, 0.1), even.Solve(compress(even), nullptr, 0.0), 0.02);
}

// A compressed edge's points lie on the homography its pairs fit, and stand for all of them.
TEST(FrameGraph, CompressEdgeSamplesTheHomographyItsPairsFit) {
  const cv::Matx33d H(0.98, -0.05, 120, 0.04, 1.01, -30, 1e-5, -2e-5, 1);
  GraphEdge e;
  for (int y = 10; y < 300; y += 17)
    for (int x = 5; x < 250; x += 13) {
      e.in_a.emplace_back(float(x), float(y));
      e.in_b.emplace_back(ApplyHomography(H, cv::Point2d(x, y)));
    }
  const int n = static_cast<int>(e.in_a.size());
  const GraphEdge c = CompressEdge(e, 9);
  ASSERT_EQ(c.in_a.size(), 9u);
  ASSERT_EQ(c.weight.size(), 9u);
  EXPECT_EQ(c.Matches(), n);
  EXPECT_LT(c.scatter_px, 1e-3);
  for (size_t k = 0; k < c.in_a.size(); ++k)
    EXPECT_LT(cv::norm(ApplyHomography(H, cv::Point2d(c.in_a[k])) - cv::Point2d(c.in_b[k])), 1e-2);
  // Its error through a placement is the pairs' error: here two cameras whose plane homography
  // is not H (the edge is 2 px or more off everywhere).
  const cv::Size frame(400, 300);
  const cv::Matx33d K = CameraMatrix(400, frame);
  PlanePose b = ReferencePose(K);
  b.centre[0] += 2;
  const std::vector<PlanePose> poses{ReferencePose(K), b};
  EXPECT_NEAR(PlaneTransferRms(poses, 400, frame, {LinkOf(c, 0, 1)}), PlaneTransferRms(poses, 400, frame, {LinkOf(e, 0, 1)}),
              0.05);
  double count = 0;
  for (float w : c.weight) count += double(w) * w;
  EXPECT_NEAR(count, n, 1e-3);
  // Too few pairs to stand for: kept as they are.
  GraphEdge small;
  small.in_a.assign(e.in_a.begin(), e.in_a.begin() + 8);
  small.in_b.assign(e.in_b.begin(), e.in_b.begin() + 8);
  EXPECT_TRUE(CompressEdge(small, 9).weight.empty());
  EXPECT_EQ(CompressEdge(small, 9).in_a.size(), 8u);
  // No compression asked for.
  EXPECT_EQ(CompressEdge(e, 0).in_a.size(), e.in_a.size());
}

}  // namespace
}  // namespace rolamos
