#include "align/graph_solve.h"

#include <gtest/gtest.h>

#include "geometry/plane_camera.h"

namespace rolamos {
namespace {

// Three frames 150 px apart; edges from where `truth` puts a grid of a's pixels in b.
struct Line {
  FrameGraph g;
  std::vector<PlanePose> truth;
  Line() {
    g.frame = cv::Size(400, 300);
    g.focal = 400;
    g.K = CameraMatrix(g.focal, g.frame);
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
  void Add(int a, int b, EdgeKind kind) {
    GraphEdge e;
    e.a = a;
    e.b = b;
    e.kind = kind;
    const cv::Matx33d H = PlaneToFrame(truth[size_t(b)], g.K) * FrameToPlane(truth[size_t(a)], g.K);
    for (int y = 50; y < 300; y += 100)
      for (int x = 200; x < 400; x += 60) {
        const cv::Vec3d q = H * cv::Vec3d(x, y, 1);
        e.in_a.emplace_back(float(x), float(y));
        e.in_b.emplace_back(float(q[0] / q[2]), float(q[1] / q[2]));
      }
    g.edges.push_back(e);
    g.AddLinked(a, b);
  }
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

}  // namespace
}  // namespace rolamos
