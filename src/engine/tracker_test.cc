#include "engine/tracker.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "engine/lucas_kanade.h"
#include "engine/motion_gate.h"
#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

cv::Point2f Apply(const cv::Matx33d& H, cv::Point2f p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
  return {float(q[0] / q[2]), float(q[1] / q[2])};
}

// A frame of the procedural seafloor and the same ground seen through `H` (frame -> next frame).
void FramePair(cv::Size size, const cv::Matx33d& H, cv::Mat* a, cv::Mat* b) {
  const cv::Mat ground = RenderSeafloor(0, 0, size.width + 200, size.height + 200);
  *a = ground(cv::Rect(100, 100, size.width, size.height)).clone();
  const cv::Matx33d shift(1, 0, -100, 0, 1, -100, 0, 0, 1);  // ground -> frame a
  cv::warpPerspective(ground, *b, cv::Mat(H * shift), size, cv::INTER_CUBIC, cv::BORDER_REFLECT);
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// Frames are followed halved until the tracking image holds at most the pixels asked for (exact
// averages), and, for a video codec's frames, at least once unless small.
TEST(Tracker, ScaleHalvesUntilTheTrackingImageIsSmallEnough) {
  TrackerOptions o;
  o.track_pixels = 0.6e6;
  EXPECT_EQ(o.ScaleFor({480, 360}), 1.0);
  EXPECT_EQ(o.ScaleFor({640, 480}), 1.0);
  EXPECT_EQ(o.ScaleFor({800, 600}), 1.0);
  EXPECT_EQ(o.ScaleFor({1024, 768}), 0.5);
  EXPECT_EQ(o.ScaleFor({1292, 964}), 0.5);
  EXPECT_EQ(o.ScaleFor({1920, 1080}), 0.5);
  EXPECT_EQ(o.ScaleFor({3840, 2160}), 0.25);
  EXPECT_EQ(o.ScaleFor({200, 100}), 1.0);  // never enlarged
  EXPECT_EQ(o.PointsFor({3840, 2160}), o.max_points);  // stills at a quarter
  EXPECT_EQ(o.WindowFor({3840, 2160}), o.halved_window);  // stills followed halved or less
  o.halve_once = true;
  EXPECT_EQ(o.ScaleFor({480, 360}), 1.0);  // under 0.4 of track_pixels
  EXPECT_EQ(o.ScaleFor({640, 480}), 0.5);
  EXPECT_EQ(o.ScaleFor({800, 600}), 0.5);
  EXPECT_EQ(o.ScaleFor({1280, 720}), 0.5);
  // Large video frames then go on down to codec_pixels.
  EXPECT_EQ(o.ScaleFor({1292, 964}), 0.25);
  EXPECT_EQ(o.ScaleFor({1920, 1080}), 0.25);
  EXPECT_EQ(o.ScaleFor({3840, 2160}), 0.125);
  // ...and hand on twice the points there, followed in smaller windows; at half size the points
  // asked for, in halved_window; at full size (under 0.4 of track_pixels) in `window`.
  o.max_points = 300;
  EXPECT_EQ(o.PointsFor({1292, 964}), 600);
  EXPECT_EQ(o.PointsFor({800, 600}), 300);
  o.window = 31;
  o.halved_window = 21;
  o.quarter_window = 13;
  EXPECT_EQ(o.WindowFor({1292, 964}), 13);
  EXPECT_EQ(o.WindowFor({1920, 1080}), 13);
  EXPECT_EQ(o.WindowFor({800, 600}), 21);
  EXPECT_EQ(o.WindowFor({1280, 720}), 21);
  EXPECT_EQ(o.WindowFor({480, 360}), 31);
  o.codec_pixels = 1e6;  // or track_pixels, the smaller
  EXPECT_EQ(o.ScaleFor({1292, 964}), 0.5);
  EXPECT_EQ(o.ScaleFor({3840, 2160}), 0.25);
  std::string error;
  EXPECT_TRUE(o.IsValid(&error)) << error;
  o.quarter_window = 3;
  EXPECT_FALSE(o.IsValid(&error));
  o.quarter_window = 13;
  // Stills: the window at full size, halved_window where they are followed halved.
  o.halve_once = false;
  o.track_pixels = 0.6e6;
  o.window = 31;
  o.halved_window = 21;
  EXPECT_EQ(o.WindowFor({800, 600}), 31);
  EXPECT_EQ(o.WindowFor({640, 480}), 31);
  EXPECT_EQ(o.WindowFor({1292, 964}), 21);
  EXPECT_EQ(o.WindowFor({1920, 1080}), 21);
  EXPECT_EQ(o.PointsFor({1292, 964}), 300);
  o.halved_window = 62;
  EXPECT_FALSE(o.IsValid(&error));
  o.halved_window = 21;
  o.track_pixels = 10;
  EXPECT_FALSE(o.IsValid(&error));
}

// Points followed through a known homography land within a small fraction of a pixel of where
// it puts them, at full size and at half size, even from a start a few pixels off.
TEST(Tracker, FollowsAKnownHomographyToSubpixel) {
  const cv::Matx33d H(0.995, -0.035, 31, 0.035, 0.995, -17, 2e-6, -3e-6, 1);
  cv::Mat a, b;
  FramePair({800, 600}, H, &a, &b);
  for (const double pixels : {1e6, 0.3e6}) {
    TrackerOptions o;
    o.track_pixels = pixels;
    const FrameTracker tracker(o);
    const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
    const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
    ASSERT_GT(points.size(), 200u);
    const cv::Matx33d off(1, 0, 3.5, 0, 1, -2.5, 0, 0, 1);  // the start, off by 4 px
    const TrackFlow flow = tracker.Follow(*ta, *tb, points, off * H);
    std::vector<double> errors;
    for (size_t i = 0; i < points.size(); ++i) {
      const cv::Point2f truth = Apply(H, points[i]);
      if (!flow.ok[i] || truth.x < 12 || truth.y < 12 || truth.x > 788 || truth.y > 588) continue;
      errors.push_back(cv::norm(flow.to[i] - truth));
    }
    // A tenth of a tracking pixel.
    const double scale = o.ScaleFor(a.size());
    ASSERT_GT(errors.size(), 150u) << "scale " << scale;
    EXPECT_LT(Median(errors), 0.1 / scale) << "scale " << scale;
    EXPECT_EQ(flow.followed, static_cast<int>(std::count(flow.ok.begin(), flow.ok.end(), 1)));
  }
}

// A keyframe's windows, shared by the engine and the keyframe's job (two threads at once): made
// once, and a follow from them finds what a follow that makes its own finds.
TEST(Tracker, WindowsSharedByTwoThreadsAreMadeOnceAndFollowTheSame) {
  const cv::Matx33d H(0.995, -0.035, 31, 0.035, 0.995, -17, 2e-6, -3e-6, 1);
  cv::Mat a, b;
  FramePair({800, 600}, H, &a, &b);
  const TrackerOptions options;
  const FrameTracker tracker(options);
  const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
  ASSERT_EQ(ta->scale, 1.0);  // tracking pixels are frame pixels
  const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
  ASSERT_GT(points.size(), 200u);
  SharedWindows shared;
  std::atomic<int> made{0};
  const auto make = [&] {
    ++made;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));  // the other thread asks meanwhile
    return PrepareLucasKanade(ta->pyramid, points, cv::Size(options.window, options.window), options.levels, 1e-4);
  };
  const LucasKanadeTemplates* seen[2] = {nullptr, nullptr};
  std::thread other([&] { seen[0] = &shared.Get(make); });
  seen[1] = &shared.Get(make);
  other.join();
  EXPECT_EQ(made.load(), 1);
  EXPECT_EQ(seen[0], seen[1]);
  const TrackFlow alone = tracker.Follow(*ta, *tb, points, H);
  const TrackFlow from_shared = tracker.Follow(*ta, *tb, points, H, &shared);
  EXPECT_EQ(made.load(), 1);
  ASSERT_GT(alone.followed, 200);
  EXPECT_EQ(from_shared.followed, alone.followed);
  for (size_t i = 0; i < points.size(); ++i) {
    ASSERT_EQ(from_shared.ok[i], alone.ok[i]) << i;
    if (alone.ok[i]) EXPECT_LT(cv::norm(from_shared.to[i] - alone.to[i]), 1e-3) << i;
  }
}

// A follow that may give up: from a good start, every point is followed exactly as by the whole
// follow (the sample first, then the rest), with shared windows and without; into a frame of
// open water, where the whole follow keeps almost nothing, it gives up after the sample.
TEST(Tracker, AFollowThatMayGiveUpFollowsTheSameOrGivesUpAfterItsSample) {
  const cv::Matx33d H(0.995, -0.035, 31, 0.035, 0.995, -17, 2e-6, -3e-6, 1);
  cv::Mat a, b;
  FramePair({800, 600}, H, &a, &b);
  const FrameTracker tracker(TrackerOptions{});
  const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
  const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
  ASSERT_GT(points.size(), 200u);
  const cv::Matx33d off(1, 0, 3.5, 0, 1, -2.5, 0, 0, 1);
  for (const bool shared_windows : {false, true}) {
    SharedWindows shared;
    const TrackFlow whole = tracker.Follow(*ta, *tb, points, off * H);
    const TrackFlow sampled = tracker.Follow(*ta, *tb, points, off * H, shared_windows ? &shared : nullptr, true);
    EXPECT_FALSE(sampled.cut_short);
    ASSERT_GT(whole.followed, 200);
    EXPECT_EQ(sampled.followed, whole.followed);
    for (size_t i = 0; i < points.size(); ++i) {
      ASSERT_EQ(sampled.ok[i], whole.ok[i]) << i;
      if (whole.ok[i]) EXPECT_EQ(sampled.to[i], whole.to[i]) << i;
    }
  }
  // Open water: the follow finds next to nothing.
  const auto other = tracker.Prepare(cv::Mat(600, 800, CV_8UC1, cv::Scalar(90)));
  const TrackFlow whole = tracker.Follow(*ta, *other, points, H);
  const TrackFlow sampled = tracker.Follow(*ta, *other, points, H, nullptr, true);
  ASSERT_LT(whole.followed, 0.05 * double(points.size())) << "open water is followed";
  EXPECT_TRUE(sampled.cut_short);
  EXPECT_LE(sampled.followed, whole.followed);
  // Only the sample (every fourth point) was followed.
  for (size_t i = 0; i < points.size(); ++i)
    if (i % 4 != 0) EXPECT_FALSE(sampled.ok[i]) << i;
}

// Turned by 20 degrees (a vehicle's turn a few frames from its keyframe), with the guess off by
// a few pixels: square windows that do not turn lose points and place the rest worse; followed in
// the frame turned back (the default), as many points as unturned are followed, to a tenth of a
// tracking pixel.
TEST(Tracker, FollowsATurnedFrameInACopyTurnedBack) {
  const double turn = 20 * CV_PI / 180;
  const cv::Matx33d about(1, 0, -400, 0, 1, -300, 0, 0, 1);
  const cv::Matx33d H = about.inv() * cv::Matx33d(std::cos(turn), -std::sin(turn), 12, std::sin(turn),
                                                  std::cos(turn), -7, 0, 0, 1) * about;
  cv::Mat a, b;
  FramePair({800, 600}, H, &a, &b);
  auto follow = [&](double turn_deg, std::vector<double>* errors) {
    TrackerOptions o;
    o.turn_deg = turn_deg;
    const FrameTracker tracker(o);
    const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
    const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
    const cv::Matx33d off(1, 0, 1.5, 0, 1, -1.0, 0, 0, 1);
    const TrackFlow flow = tracker.Follow(*ta, *tb, points, off * H);
    for (size_t i = 0; i < points.size(); ++i) {
      const cv::Point2f truth = Apply(H, points[i]);
      if (!flow.ok[i] || truth.x < 12 || truth.y < 12 || truth.x > 788 || truth.y > 588) continue;
      errors->push_back(cv::norm(flow.to[i] - truth));
    }
    EXPECT_EQ(flow.followed, static_cast<int>(std::count(flow.ok.begin(), flow.ok.end(), 1)));
    return o.ScaleFor(a.size());
  };
  std::vector<double> square, turned;
  follow(0, &square);
  const double scale = follow(TrackerOptions().turn_deg, &turned);
  ASSERT_GT(turned.size(), 150u);
  EXPECT_GT(turned.size(), square.size() + 20);
  EXPECT_LT(Median(turned), 0.1 / scale);
  ASSERT_FALSE(square.empty());
  EXPECT_LT(Median(turned), 0.7 * Median(square));

  TrackerOptions bad;
  bad.turn_deg = -1;
  std::string error;
  EXPECT_FALSE(bad.IsValid(&error));
  EXPECT_NE(error.find("turn"), std::string::npos);
}

// A point whose ground leaves the frame (or lands on an overlay) is not taken as followed.
TEST(Tracker, PointsOutsideTheNextFrameOrOnAnOverlayAreNotFollowed) {
  const cv::Matx33d H(1, 0, 260, 0, 1, 0, 0, 0, 1);  // a third of the frame moves out
  cv::Mat a, b;
  FramePair({640, 480}, H, &a, &b);
  const FrameTracker tracker(TrackerOptions{});
  cv::Mat overlay(b.size(), CV_8U, cv::Scalar(255));
  overlay(cv::Rect(300, 0, 120, 480)).setTo(0);
  const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b, overlay);
  const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
  const TrackFlow flow = tracker.Follow(*ta, *tb, points, H);
  int gone = 0, followed_out = 0, on_overlay = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    const cv::Point2f truth = Apply(H, points[i]);
    const bool out = truth.x > 639;
    gone += out;
    followed_out += out && flow.ok[i];
    on_overlay += flow.ok[i] && flow.to[i].x > 300 && flow.to[i].x < 420;
  }
  EXPECT_GT(gone, 50);
  EXPECT_EQ(followed_out, 0);
  EXPECT_EQ(on_overlay, 0);
}

// Corners spread over the frame, away from the points it has and from overlays.
TEST(Tracker, CornersSpreadAndAvoidOverlays) {
  const cv::Mat frame = RenderSeafloor(0, 0, 640, 480);
  cv::Mat usable(frame.size(), CV_8U, cv::Scalar(255));
  usable(cv::Rect(0, 0, 640, 60)).setTo(0);  // a timestamp bar
  const FrameTracker tracker(TrackerOptions{});
  const auto t = tracker.Prepare(frame, usable);
  const std::vector<cv::Point2f> existing = {{320, 240}, {100, 300}};
  const std::vector<cv::Point2f> corners = tracker.Corners(*t, existing, 200);
  ASSERT_GT(corners.size(), 150u);
  int quadrants[4] = {0, 0, 0, 0};
  for (const auto& c : corners) {
    EXPECT_GT(c.y, 60) << "on the overlay";
    for (const auto& e : existing) EXPECT_GT(cv::norm(c - e), 5.0);
    ++quadrants[(c.x >= 320) + 2 * (c.y >= 240)];
  }
  for (int q : quadrants) EXPECT_GT(q, 20);
}

// Open water after the seafloor: the keyframe's points, followed into a frame of noise, are not
// taken as followed (the engine then finds the frame featureless and rejects it). At both scales.
TEST(Tracker, SeafloorPointsAreNotFollowedIntoOpenWater) {
  for (const cv::Size size : {cv::Size(480, 360), cv::Size(640, 480)}) {
    const cv::Mat seafloor = RenderSeafloor(0, 0, size.width, size.height);
    cv::Mat water(size, CV_8UC3);
    cv::RNG rng(7);
    rng.fill(water, cv::RNG::NORMAL, cv::Scalar(90, 70, 20), cv::Scalar(3, 3, 3));
    const FrameTracker tracker(TrackerOptions{});
    const auto ta = tracker.Prepare(seafloor), tb = tracker.Prepare(water);
    const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
    ASSERT_GT(points.size(), 200u);
    const TrackFlow flow = tracker.Follow(*ta, *tb, points, cv::Matx33d::eye());
    EXPECT_LT(flow.followed, static_cast<int>(points.size() / 10)) << size.width;
  }
}

// Without a prediction the coarse phase correlation finds a large shift the pyramid alone
// would not.
TEST(Tracker, CoarseShiftFindsALargeTranslation) {
  const cv::Matx33d H(1, 0, -150, 0, 1, 95, 0, 0, 1);
  cv::Mat a, b;
  FramePair({640, 480}, H, &a, &b);
  const FrameTracker tracker(TrackerOptions{});
  const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
  double response = 0;
  const cv::Matx33d found = tracker.CoarseShift(*ta, *tb, cv::Matx33d::eye(), &response);
  EXPECT_GT(response, 0.05);
  EXPECT_NEAR(found(0, 2), -150, 8);
  EXPECT_NEAR(found(1, 2), 95, 8);
}

// A still turned by 35 degrees and moved, with no idea of either: CoarseTurn tries turns and
// finds this one, and the frame is followed from there; from CoarseShift's start it is not.
TEST(Tracker, CoarseTurnFindsATurnNothingForesaw) {
  const double turn = -35 * CV_PI / 180;
  const cv::Matx33d about(1, 0, -400, 0, 1, -300, 0, 0, 1);
  const cv::Matx33d H = about.inv() * cv::Matx33d(std::cos(turn), -std::sin(turn), 60, std::sin(turn),
                                                  std::cos(turn), -45, 0, 0, 1) * about;
  cv::Mat a, b;
  FramePair({800, 600}, H, &a, &b);
  TrackerOptions searching;
  searching.turn_search_deg = 84;
  const FrameTracker tracker(searching);
  const auto ta = tracker.Prepare(a), tb = tracker.Prepare(b);
  const std::vector<cv::Point2f> points = tracker.Corners(*ta, {}, 300);
  auto right = [&](const cv::Matx33d& start) {
    const TrackFlow flow = tracker.Follow(*ta, *tb, points, start);
    int n = 0;
    for (size_t i = 0; i < points.size(); ++i) n += flow.ok[i] && cv::norm(flow.to[i] - Apply(H, points[i])) < 0.3;
    return n;
  };
  double turned = 0, square = 0;
  const cv::Matx33d start = tracker.CoarseTurn(*ta, *tb, cv::Matx33d::eye(), &turned);
  const cv::Matx33d shifted = tracker.CoarseShift(*ta, *tb, cv::Matx33d::eye(), &square);
  EXPECT_GT(turned, 0.05);
  EXPECT_NEAR(MotionOf(start, a.size()).rotation, MotionOf(H, a.size()).rotation, 3 * CV_PI / 180);
  // Where the start puts the frame's centre, against the truth: within Lucas-Kanade's reach.
  EXPECT_LT(cv::norm(Apply(start, {400, 300}) - Apply(H, {400, 300})), 12);
  const int found = right(start), lost = right(shifted);
  EXPECT_GT(found, 150);
  EXPECT_LT(lost, found / 3);

  // No turn searched (the default): the guess, and no response.
  double none = 1;
  EXPECT_EQ(FrameTracker(TrackerOptions{}).CoarseTurn(*ta, *tb, shifted, &none), shifted);
  EXPECT_EQ(none, 0);

  TrackerOptions bad;
  bad.turn_search_step_deg = 0;
  std::string error;
  EXPECT_FALSE(bad.IsValid(&error));
  EXPECT_NE(error.find("turn search"), std::string::npos);
}

// The points followed both ways, paired with where they started, in order.
TEST(TrackFlow, KeptPairsThePointsFollowedWithWhereTheyStarted) {
  TrackFlow flow;
  flow.to = {{10, 11}, {20, 21}, {30, 31}};
  flow.ok = {1, 0, 1};
  const std::vector<cv::Point2f> points{{1, 2}, {3, 4}, {5, 6}};
  std::vector<cv::Point2f> landed, started;
  std::vector<size_t> which;
  flow.Kept(points, &landed, &started, &which);
  EXPECT_EQ(landed, (std::vector<cv::Point2f>{{10, 11}, {30, 31}}));
  EXPECT_EQ(started, (std::vector<cv::Point2f>{{1, 2}, {5, 6}}));
  EXPECT_EQ(which, (std::vector<size_t>{0, 2}));
}

}  // namespace
}  // namespace rolamos
