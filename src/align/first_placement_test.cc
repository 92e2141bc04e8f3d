#include "align/first_placement.h"

#include <cmath>

#include <gtest/gtest.h>

#include "geometry/plane_camera.h"
#include "util/homography.h"

namespace rolamos {
namespace {

// One patch of ten frames in a row, 500 px apart over the seafloor plane, seen through a lens 90
// degrees across (800 x 600, focal 400); the engine placed them right. The first frame, the part's
// root, is pitched by `root_pitch_deg`, the others level.
FrameGraph Row(double root_pitch_deg, std::vector<PlanePose>* truth) {
  FrameGraph g;
  g.frame = cv::Size(800, 600);
  g.focal = 400;
  g.K = CameraMatrix(g.focal, g.frame);
  PatchSidecar s;
  s.id = 1;
  g.sidecars[1] = s;
  for (int i = 0; i < 10; ++i) {
    PlanePose p = ReferencePose(g.K);
    p.centre[0] += 500.0 * i;
    if (i == 0) p.pitch = root_pitch_deg * CV_PI / 180;
    truth->push_back(p);
    GraphNode n;
    n.patch = 1;
    n.index = i;
    n.record = size_t(i);
    n.to_patch = FrameToPlane(p, g.K);
    g.node_of[{1, i}] = i;
    g.nodes.push_back(n);
  }
  for (int i = 0; i + 1 < 10; ++i) {
    GraphEdge e;
    e.a = i;
    e.b = i + 1;
    e.kind = kOnline;
    g.AddLinked(i, i + 1);
    g.edges.push_back(e);
  }
  return g;
}

// The map's plane is the seafloor's, not the root frame's image plane: with a root pitched by 6
// degrees, that plane's horizon lies 3,800 px away, and frames past it were placed folded over
// (behind the camera) as the start of the global solve.
TEST(FirstPlacement, APitchedRootFrameDoesNotTiltTheMapsPlane) {
  for (double pitch : {0.0, 6.0}) {
    SCOPED_TRACE("root pitched " + std::to_string(pitch) + " degrees");
    std::vector<PlanePose> truth;
    const FrameGraph g = Row(pitch, &truth);
    UnionFind comp(0);
    const std::vector<cv::Matx33d> G = PlaceFirst(g, &comp);
    ASSERT_EQ(G.size(), 10u);
    const cv::Point2d centre((g.frame.width - 1) / 2.0, (g.frame.height - 1) / 2.0);
    for (int i = 1; i < 10; ++i) {
      // In front of the camera at every corner, and the frames as far apart as on the seafloor.
      for (const cv::Point2d corner : {cv::Point2d(0, 0), cv::Point2d(799, 0), cv::Point2d(799, 599), cv::Point2d(0, 599)}) {
        const cv::Vec3d q = G[size_t(i)] * cv::Vec3d(corner.x, corner.y, 1);
        EXPECT_GT(q[2] * G[0](2, 2), 0) << "frame " << i;
      }
      const double step = cv::norm(ApplyHomography(G[size_t(i)], centre) - ApplyHomography(G[size_t(i - 1)], centre));
      const double truth_step = cv::norm(ApplyHomography(FrameToPlane(truth[size_t(i)], g.K), centre) -
                                         ApplyHomography(FrameToPlane(truth[size_t(i - 1)], g.K), centre));
      EXPECT_NEAR(step, truth_step, 0.02 * truth_step) << "frame " << i;
    }
  }
}

}  // namespace
}  // namespace rolamos
