#include "align/edge_consistency.h"

#include <gtest/gtest.h>

#include "align/frame_confidence.h"
#include "util/homography.h"

namespace rolamos {
namespace {

// Two lanes of one patch, the engine's chain along them (lane A left to right, a turn, lane B right
// to left, 300 px below): frame i's true placement is a translation.
struct TwoLanes {
  static constexpr int kLane = 40;
  static constexpr double kStep = 120, kLaneGap = 300;
  FrameGraph g;
  std::vector<cv::Matx33d> truth;

  TwoLanes() {
    g.frame = cv::Size(480, 360);
    g.focal = 420;
    g.K = CameraMatrix(g.focal, g.frame);
    PatchSidecar s;
    s.id = 1;
    g.sidecars[1] = s;
    for (int i = 0; i < 2 * kLane; ++i) {
      const bool b = i >= kLane;
      const double x = b ? (2 * kLane - 1 - i) * kStep : i * kStep, y = b ? kLaneGap : 0;
      truth.push_back(cv::Matx33d(1, 0, x, 0, 1, y, 0, 0, 1));
      GraphNode n;
      n.patch = 1;
      n.index = i;
      n.record = size_t(i);
      n.to_patch = truth.back();  // the engine placed them right
      g.node_of[{1, i}] = i;
      g.nodes.push_back(n);
    }
    for (int i = 0; i + 1 < 2 * kLane; ++i) Add(i, i + 1, kOnline, cv::Matx33d::eye());
  }
  // An edge a -> b whose matched pixels follow the truth, moved by `error` (in b's pixels).
  void Add(int a, int b, EdgeKind kind, const cv::Matx33d& error) {
    GraphEdge e;
    e.a = a;
    e.b = b;
    e.kind = kind;
    const cv::Matx33d a_to_b = error * truth[size_t(b)].inv() * truth[size_t(a)];
    for (int y = 20; y < g.frame.height; y += 40)
      for (int x = 20; x < g.frame.width; x += 40) {
        const cv::Point2d q = ApplyHomography(a_to_b, cv::Point2d(x, y));
        e.in_a.emplace_back(float(x), float(y));
        e.in_b.emplace_back(q);
      }
    g.AddLinked(a, b);
    g.edges.push_back(std::move(e));
  }
};

// 50 appearance edges joining the two lanes with one consistent wrong offset (look-alike ground
// three frames along) are found and dropped; 20 true ones between the same lanes stay.
TEST(EdgeConsistency, APlantedFalseSetThatAgreesWithItselfIsFoundAndDropped) {
  TwoLanes l;
  const size_t first = l.g.edges.size();
  // True edges: lane A frame i over lane B's frame at the same x (300 px below).
  for (int i = 0; i < 20; ++i) l.Add(i, 2 * TwoLanes::kLane - 1 - i, kRetrieval, cv::Matx33d::eye());
  // False: the same pairs' neighbours, all shifted by 3 frame steps and turned half about.
  const cv::Matx33d wrong = cv::Matx33d(-1, 0, 480, 0, -1, 360, 0, 0, 1) * cv::Matx33d(1, 0, 3 * TwoLanes::kStep, 0, 1, 0, 0, 0, 1);
  for (int i = 0; i < 50; ++i) l.Add(i % 35, 2 * TwoLanes::kLane - 1 - (i % 35) - 2, kRetrieval, wrong);
  AlignOptions o;
  const ConsistencyReport r = CheckAppearanceEdges(l.g, o, {}, ParallelForOptions{});
  int true_dropped = 0, false_dropped = 0;
  for (size_t k = first; k < l.g.edges.size(); ++k) (k < first + 20 ? true_dropped : false_dropped) += r.drop[k];
  EXPECT_EQ(true_dropped, 0);
  EXPECT_EQ(false_dropped, 50);
  EXPECT_EQ(r.dropped_edges, 50);
  ASSERT_FALSE(r.rejected.empty());
  EXPECT_NE(r.rejected[0].joined.find("patch 1"), std::string::npos) << r.rejected[0].joined;
  EXPECT_NE(r.rejected[0].reason.find("chain"), std::string::npos);
  // The engine's own links are never judged.
  for (size_t k = 0; k < first; ++k) EXPECT_FALSE(r.drop[k]);
  RemoveEdges(l.g, r.drop);
  EXPECT_EQ(l.g.edges.size(), first + 20);
}

// Drift is allowed: an edge between frames far apart along the chain may disagree with it by more
// than one between neighbours.
TEST(EdgeConsistency, ChainDriftGrowsWithTheDistanceAlongIt) {
  TwoLanes l;
  const size_t first = l.g.edges.size();
  const cv::Matx33d drifted(1, 0, 150, 0, 1, 0, 0, 0, 1);  // 150 px: a quarter of a diagonal
  l.Add(0, 2 * TwoLanes::kLane - 1, kRetrieval, drifted);  // 79 frames apart along the chain
  AlignOptions o;
  EXPECT_FALSE(CheckAppearanceEdges(l.g, o, {}, ParallelForOptions{}).drop[first]);
  o.chain_drift = 0;
  o.chain_tolerance = 0.1;
  EXPECT_TRUE(CheckAppearanceEdges(l.g, o, {}, ParallelForOptions{}).drop[first]);
}

// Between parts the engine's chain does not join (tracking lost between the lanes), two sets of
// appearance edges place lane B on lane A: the true one (20 edges) and a larger false one (30,
// one consistent wrong offset). The navigation decides: the false set is dropped and reported.
TEST(EdgeConsistency, BetweenUnjoinedPartsTheNavigationPicksTheTrueSet) {
  TwoLanes l;
  // Lane B is its own patch, no engine link to lane A.
  PatchSidecar b;
  b.id = 2;
  l.g.sidecars[2] = b;
  for (int i = TwoLanes::kLane; i < 2 * TwoLanes::kLane; ++i) l.g.nodes[size_t(i)].patch = 2;
  l.g.edges.erase(l.g.edges.begin() + (TwoLanes::kLane - 1));
  // In its own patch, lane B's frames are placed from its first frame.
  for (int i = TwoLanes::kLane; i < 2 * TwoLanes::kLane; ++i)
    l.g.nodes[size_t(i)].to_patch = l.truth[size_t(TwoLanes::kLane)].inv() * l.truth[size_t(i)];
  const size_t first = l.g.edges.size();
  for (int i = 0; i < 20; ++i) l.Add(i, 2 * TwoLanes::kLane - 1 - i, kRetrieval, cv::Matx33d::eye());
  const cv::Matx33d wrong(1, 0, 5 * TwoLanes::kStep, 0, 1, 40, 0, 0, 1);
  for (int i = 0; i < 30; ++i) l.Add(i + 5, 2 * TwoLanes::kLane - 1 - i, kRetrieval, wrong);
  // Navigation: every fifth frame's centre where it truly is (metres = pixels here).
  std::vector<NavigationFix> nav;
  for (int i = 0; i < 2 * TwoLanes::kLane; i += 5)
    nav.push_back({i, cv::Point2d(240, 180), ApplyHomography(l.truth[size_t(i)], cv::Point2d(240, 180))});
  AlignOptions o;
  const ConsistencyReport r = CheckAppearanceEdges(l.g, o, nav, ParallelForOptions{});
  int true_dropped = 0, false_dropped = 0;
  for (size_t k = first; k < l.g.edges.size(); ++k) (k < first + 20 ? true_dropped : false_dropped) += r.drop[k];
  EXPECT_EQ(true_dropped, 0);
  EXPECT_EQ(false_dropped, 30);
  ASSERT_EQ(r.rejected.size(), 1u);
  EXPECT_NE(r.rejected[0].reason.find("navigation"), std::string::npos) << r.rejected[0].reason;
  EXPECT_NE(r.rejected[0].joined.find("patch 2"), std::string::npos) << r.rejected[0].joined;
}

// The uncertainty follows how a frame is held: a lane joined to the rest through one link swings
// about it (high, and more the farther from the link), while frames in the middle of well-linked
// lanes are known to about their residual.
TEST(FrameConfidence, ALaneJoinedByOneLinkIsUnsureAndWellLinkedLanesAreNot) {
  // Lanes of 10 frames, 100 px apart along, lanes 300 px apart. Lanes 0 and 1 linked frame by frame
  // (and along); lane 2 joined to lane 1 by a single link at its first frame.
  const int lane = 10;
  std::vector<cv::Point2d> centre;
  for (int l = 0; l < 3; ++l)
    for (int i = 0; i < lane; ++i) centre.emplace_back(i * 100.0, l * 300.0);
  std::vector<std::pair<int, int>> edges;
  for (int l = 0; l < 3; ++l)
    for (int i = 0; i + 1 < lane; ++i) edges.push_back({l * lane + i, l * lane + i + 1});
  for (int i = 0; i < lane; ++i) edges.push_back({i, lane + i});  // lanes 0 and 1, side by side
  for (int i = 0; i + 2 < lane; ++i) edges.push_back({2 * lane + i, 2 * lane + i + 2});  // lane 2 along, longer baselines
  edges.push_back({lane, 2 * lane});  // the one link
  const std::vector<double> residual(edges.size(), 0.4);
  const std::vector<int> anchor(centre.size(), 5);
  const std::vector<double> u = GraphUncertainty(int(centre.size()), edges, residual, centre, anchor, 600.0);
  for (int i = 0; i < 2 * lane; ++i) EXPECT_EQ(u[size_t(i)], 0.0) << "frame " << i << " is held by a web of links";
  for (int i = 2 * lane; i < 3 * lane; ++i) EXPECT_GT(u[size_t(i)], 0.4) << "frame " << i << " rests on one link";
  EXPECT_GT(u[size_t(3 * lane - 1)], u[size_t(2 * lane)]) << "the farther from the link, the less sure";
}

}  // namespace
}  // namespace rolamos
