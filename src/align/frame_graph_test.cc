#include "align/frame_graph.h"

#include <algorithm>

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// A frame of `count` random SIFT-like descriptors at points spread over 640 x 480.
GraphNode RandomNode(int patch, int index, int count, cv::RNG& rng) {
  GraphNode n;
  n.patch = patch;
  n.index = index;
  n.descriptors = cv::Mat(count, 128, CV_8U);
  rng.fill(n.descriptors, cv::RNG::UNIFORM, 0, 256);
  for (int i = 0; i < count; ++i) n.points.emplace_back(rng.uniform(20.f, 620.f), rng.uniform(20.f, 460.f));
  return n;
}

// Two frames of two patches no link joins, that share 20 features: fewer than the 25 inliers an
// appearance edge needs, as across the dark edges of the lights' cone; and a third frame of a
// third patch that shares none (retrieval wants three frames at least).
FrameGraph TwoPartsSharing20() {
  cv::RNG rng(5);
  FrameGraph g;
  g.frame = cv::Size(640, 480);
  GraphNode a = RandomNode(1, 10, 100, rng), b = RandomNode(2, 40, 80, rng);  // retrieval wants 4 a word
  for (int i = 0; i < 20; ++i) {
    // Feature i of a seen again by b, 110 px to the left and 30 down.
    cv::Mat row = a.descriptors.row(i).clone();
    b.descriptors.push_back(row);
    b.points.emplace_back(a.points[size_t(i)] + cv::Point2f(-110, 30));
  }
  g.nodes = {a, b, RandomNode(3, 70, 100, rng)};
  g.node_of[{1, 10}] = 0;
  g.node_of[{2, 40}] = 1;
  g.node_of[{3, 70}] = 2;
  return g;
}

// A frame whose ground the other shares mostly in its features beyond its primary ones (a
// degraded frame's strip along the lane beside it): 15 of the 60 shared features are among its
// first 400, too few for an edge; with all of them the pair is verified. Where the first 400
// share nothing, the pair is taken to share no ground and all are not tried.
TEST(FrameGraph, FeaturesBeyondThePrimaryOnesLinkWhatThoseDoNot) {
  cv::RNG rng(9);
  GraphNode a = RandomNode(1, 10, 400, rng), b = RandomNode(2, 40, 100, rng);
  a.primary = 400;
  GraphNode disjoint = a;  // the same frame with nothing shared among its first 400
  for (int i = 0; i < 60; ++i) {
    const cv::Point2f p(rng.uniform(120.f, 620.f), rng.uniform(20.f, 440.f));
    cv::Mat row(1, 128, CV_8U);
    rng.fill(row, cv::RNG::UNIFORM, 0, 256);
    if (i < 15) {  // in place of one of the first 400
      a.points[size_t(20 * i)] = p;
      row.copyTo(a.descriptors.row(20 * i));
    } else {
      a.points.push_back(p);
      a.descriptors.push_back(row);
    }
    disjoint.points.push_back(p);
    disjoint.descriptors.push_back(row);
    b.points.push_back(p + cv::Point2f(-110, 30));
    b.descriptors.push_back(row);
  }
  const AlignOptions o;
  const cv::Size frame(640, 480);
  GraphEdge e;
  // The first 400 alone (as stores before session 42 held): 15 pairs, fewer than 25.
  GraphNode primary_only = a;
  primary_only.points.resize(400);
  primary_only.descriptors = a.descriptors.rowRange(0, 400).clone();
  EXPECT_FALSE(VerifyPair(primary_only, b, nullptr, frame, o, &e));
  ASSERT_TRUE(VerifyPair(a, b, nullptr, frame, o, &e));
  EXPECT_GE(e.in_a.size(), 55u);
  for (size_t i = 0; i < e.in_a.size(); ++i) EXPECT_LT(cv::norm(e.in_a[i] + cv::Point2f(-110, 30) - e.in_b[i]), 0.01);
  // Guided by a guess far from the truth, the same.
  const cv::Matx33d guess(1, 0, 90, 0, 1, -60, 0, 0, 1);
  EXPECT_TRUE(VerifyPair(a, b, &guess, frame, o, &e));
  EXPECT_FALSE(VerifyPair(disjoint, b, nullptr, frame, o, &e));
}

TEST(FrameGraph, PartsLeftApartAreMatchedAgainWithFewerInliersAsked) {
  FrameGraph g = TwoPartsSharing20();
  const AlignOptions o;
  ASSERT_EQ(o.min_inliers, 25);
  AlignSummary s;
  AddRetrievalEdges(g, o, &s, {});
  EXPECT_EQ(s.retrieval_edges, 0);  // 20 shared features: not an edge at 25
  AddRejoiningEdges(g, o, &s, {});
  EXPECT_EQ(s.rejoin_tried, 3);  // every pair is across parts
  ASSERT_EQ(s.rejoin_edges, 1);  // only the two that share ground
  ASSERT_EQ(g.edges.size(), 1u);
  const GraphEdge& e = g.edges[0];
  EXPECT_EQ(std::min(e.a, e.b), 0);
  EXPECT_EQ(std::max(e.a, e.b), 1);
  EXPECT_EQ(e.kind, kRetrieval);  // checked for consistency after, like every appearance edge
  EXPECT_TRUE(g.Linked(0, 1));
  EXPECT_GE(e.Matches(), 15);
}

TEST(FrameGraph, NoRejoiningWhenTheMapIsOnePartOrItIsSwitchedOff) {
  {
    FrameGraph g = TwoPartsSharing20();
    AlignOptions o;
    o.rejoin_candidates = 0;
    AlignSummary s;
    AddRejoiningEdges(g, o, &s, {});
    EXPECT_EQ(s.rejoin_tried, 0);
    EXPECT_TRUE(g.edges.empty());
  }
  {
    FrameGraph g = TwoPartsSharing20();
    for (int other : {1, 2}) {  // the engine's links already join them all
      GraphEdge joined;
      joined.a = 0;
      joined.b = other;
      g.edges.push_back(joined);
      g.AddLinked(0, other);
    }
    AlignSummary s;
    AddRejoiningEdges(g, AlignOptions(), &s, {});
    EXPECT_EQ(s.rejoin_tried, 0);
    EXPECT_EQ(g.edges.size(), 2u);
  }
}

}  // namespace
}  // namespace rolamos
