#include "engine/keyframe_job.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include <future>

#include "synth/seafloor_texture.h"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

const cv::Size kFrame(480, 360);
const cv::Matx33d kK(420, 0, 239.5, 0, 420, 179.5, 0, 0, 1);

// The procedural seafloor seen through `to_ground` (frame pixels -> ground pixels).
cv::Mat View(const cv::Mat& ground, const cv::Matx33d& to_ground) {
  cv::Mat out;
  cv::warpPerspective(ground, out, cv::Mat(to_ground), kFrame, cv::INTER_CUBIC | cv::WARP_INVERSE_MAP,
                      cv::BORDER_REFLECT);
  return out;
}

struct Scene {
  cv::Mat ground = RenderSeafloor(0, 0, 1200, 800);
  FrameTracker tracker{TrackerOptions{}};
  // Keyframes at x = 100 and 220 on the ground; the frame followed between them at 160, turned
  // and tilted a little.
  cv::Matx33d before{1, 0, 100, 0, 1, 150, 0, 0, 1};
  cv::Matx33d after{1, 0, 220, 0, 1, 156, 0, 0, 1};
  cv::Matx33d frame{0.998, -0.02, 160, 0.02, 0.998, 152, 2e-6, -1e-6, 1};
};

KeyframeJob JobFor(const Scene& s, std::vector<FollowedFrame> followed) {
  KeyframeJob job;
  job.index = 10;
  job.to_patch = s.after;
  job.track = s.tracker.Prepare(View(s.ground, s.after), cv::Mat());
  job.points = s.tracker.Corners(*job.track, {}, 300);
  job.followed = std::move(followed);
  job.followed_from = 4;
  job.followed_from_to_patch = s.before;
  return job;
}

KeyframeTools ToolsFor(const Scene& s) {
  KeyframeTools tools;
  tools.tracker = &s.tracker;
  tools.K = kK;
  return tools;
}

// The next keyframe's points, followed back into a frame followed from the keyframe before,
// register the frame against the next keyframe where the ground truth says; the weight of the
// keyframe before goes with the inliers each registration had.
TEST(FollowBack, RegistersAFollowedFrameAgainstTheNextKeyframe) {
  const Scene s;
  FollowedFrame f;
  f.index = 7;
  f.track = s.tracker.Prepare(View(s.ground, s.frame), cv::Mat());
  f.to_before = s.before.inv() * s.frame;  // following placed it right (the guess only)
  f.inliers = 100;
  const std::vector<FollowedBetween> between = FollowBack(JobFor(s, {f}), ToolsFor(s));
  ASSERT_EQ(between.size(), 1u);
  const FollowedBetween& b = between[0];
  EXPECT_EQ(b.index, 7);
  EXPECT_EQ(b.before, 4);
  EXPECT_EQ(b.after, 10);
  EXPECT_LT(MaxCornerShift(b.to_after, s.after.inv() * s.frame, kFrame), 0.3);
  EXPECT_GT(b.weight_before, 0.0);
  EXPECT_LT(b.weight_before, 1.0);
}

// A start off by a few pixels (following's error) is still found; a frame of another size, or
// with no pyramid, is left out rather than placed from a registration that cannot be made.
TEST(FollowBack, LeavesOutFramesItCannotRegister) {
  const Scene s;
  FollowedFrame off;
  off.index = 7;
  off.track = s.tracker.Prepare(View(s.ground, s.frame), cv::Mat());
  off.to_before = s.before.inv() * cv::Matx33d(1, 0, 4, 0, 1, -3, 0, 0, 1) * s.frame;
  off.inliers = 100;
  FollowedFrame other_size = off;
  other_size.index = 8;
  other_size.track = s.tracker.Prepare(cv::Mat(200, 300, CV_8UC3, cv::Scalar(90, 100, 80)), cv::Mat());
  FollowedFrame no_pyramid = off;
  no_pyramid.index = 9;
  no_pyramid.track.reset();
  const auto between = FollowBack(JobFor(s, {off, other_size, no_pyramid}), ToolsFor(s));
  ASSERT_EQ(between.size(), 1u);
  EXPECT_EQ(between[0].index, 7);
  EXPECT_LT(MaxCornerShift(between[0].to_after, s.after.inv() * s.frame, kFrame), 0.3);
}

KeyframeFuture Ready(std::shared_ptr<const Features> features) {
  std::promise<KeyframeProducts> made;
  KeyframeProducts products;
  products.features = std::move(features);
  made.set_value(std::move(products));
  return made.get_future().share();
}

// A keyframe beside two keyframes of the lane before, 110 px from where the chain has put it,
// beyond the guided search's reach: as loop candidates both are linked, with the true pairs; as
// recent ones (guided only) neither.
TEST(RunKeyframeJob, LinksTheLaneBeforeWhereTheChainHasDriftedFromIt) {
  const cv::Size size(640, 480);
  const cv::Matx33d to_39(0.999, -0.02, 384, 0.02, 0.999, 12, 0, 0, 1);
  const cv::Matx33d to_40 = cv::Matx33d(1, 0, -144, 0, 1, 0, 0, 0, 1) * to_39;
  auto frame = std::make_shared<Features>(), again = std::make_shared<Features>();
  auto k39 = std::make_shared<Features>(), k40 = std::make_shared<Features>();
  test::TwoFeatureViews(to_39, size, frame.get(), k39.get());
  test::TwoFeatureViews(to_40, size, again.get(), k40.get());
  const cv::Matx33d patch_39(1, 0, 2000, 0, 1, 900, 0, 0, 1);
  const cv::Matx33d patch_40 = patch_39 * to_39 * to_40.inv();
  const cv::Matx33d truth = patch_39 * to_39;

  KeyframeJob job;
  job.index = 80;
  job.blend = false;
  job.frame = std::make_shared<PreparedFrame>();
  job.frame->size = size;
  job.to_patch = cv::Matx33d(1, 0, 0, 0, 1, 110, 0, 0, 1) * truth;
  KeyframeTools tools;
  tools.features = [&](PreparedFrame&) { return std::shared_ptr<const Features>(frame); };
  for (bool loop : {true, false}) {
    job.older = {{39, patch_39, Ready(k39), loop}, {40, patch_40, Ready(k40), loop}};
    const KeyframeProducts out = RunKeyframeJob(job, tools);
    if (!loop) {
      EXPECT_TRUE(out.loop_links.empty());
      continue;
    }
    ASSERT_EQ(out.loop_links.size(), 2u);
    for (const FrameLink& l : out.loop_links) {
      const cv::Matx33d to_older = l.b == 39 ? to_39 : to_40;
      EXPECT_EQ(l.a, 80);
      EXPECT_GE(l.in_a.size(), 100u) << l.b;
      double worst = 0;
      for (size_t i = 0; i < l.in_a.size(); ++i)
        worst = std::max(worst, cv::norm(ApplyHomography(to_older, cv::Point2d(l.in_a[i])) - cv::Point2d(l.in_b[i])));
      EXPECT_LT(worst, 0.5) << l.b;
    }
  }
}

TEST(BlendHomographies, PutsEachCornerBetweenTheTwoPlacements) {
  const cv::Matx33d a(1, 0, 10, 0, 1, 0, 0, 0, 1), b(1.02, 0, -10, 0, 0.98, 4, 1e-5, 0, 1);
  EXPECT_LT(MaxCornerShift(BlendHomographies(a, b, 1.0, kFrame), a, kFrame), 1e-4);
  EXPECT_LT(MaxCornerShift(BlendHomographies(a, b, 0.0, kFrame), b, kFrame), 1e-4);
  const cv::Matx33d mid = BlendHomographies(a, b, 0.25, kFrame);
  for (const cv::Point2d c : {cv::Point2d(0, 0), cv::Point2d(479, 0), cv::Point2d(479, 359), cv::Point2d(0, 359)}) {
    const cv::Point2d want = 0.25 * ApplyHomography(a, c) + 0.75 * ApplyHomography(b, c);
    EXPECT_LT(cv::norm(ApplyHomography(mid, c) - want), 1e-4);  // corners in float
  }
}

// A vehicle holding still: hundreds of frames followed from one keyframe, each with a pyramid.
TEST(FollowedSample, KeepsAtMostItsCapacitySpreadOverTheFramesFollowed) {
  FollowedSample sample(8);
  auto pyramid = std::make_shared<const TrackFrame>();
  for (int i = 1; i <= 1000; ++i) {
    sample.Add({i, pyramid, cv::Matx33d::eye(), 100});
    ASSERT_LE(sample.size(), 8u) << "after frame " << i;
  }
  const std::vector<FollowedFrame> kept = sample.Take();
  ASSERT_GE(kept.size(), 4u);
  // Evenly spread, in order, reaching the last stretch of the run.
  const int step = kept[1].index - kept[0].index;
  for (size_t i = 1; i < kept.size(); ++i) EXPECT_EQ(kept[i].index - kept[i - 1].index, step);
  EXPECT_GT(kept.back().index, 1000 - step);
  EXPECT_EQ(pyramid.use_count(), 1 + static_cast<long>(kept.size()));  // the others let go of theirs
  // Taken: the next keyframe's frames start over, every one kept up to the capacity.
  EXPECT_EQ(sample.size(), 0u);
  for (int i = 1; i <= 5; ++i) sample.Add({2000 + i, pyramid, cv::Matx33d::eye(), 100});
  const std::vector<FollowedFrame> next = sample.Take();
  ASSERT_EQ(next.size(), 5u);
  EXPECT_EQ(next.front().index, 2001);
  EXPECT_EQ(next.back().index, 2005);
}

}  // namespace
}  // namespace rolamos
