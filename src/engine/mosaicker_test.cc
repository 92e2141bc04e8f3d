#include "rolamos/mosaicker.hpp"

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/global_align.hpp"
#include "rolamos/survey.hpp"
#include "rolamos/tiled_image.hpp"
#include "store/frame_data.h"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;


MosaickerOptions FastOptions() {
  MosaickerOptions o;
  o.tiff.compression = Compression::kZstd;
  return o;
}

// Where frames land in the patch against where they are on the ground, after one best-fit
// homography for the whole patch (the measure): RMS over a 5x5 grid in every frame.
double PatchRmsError(const PatchSidecar& s, const Survey& truth) {
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : truth.frames) gt[fs::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  std::vector<cv::Point2d> grid, ours, theirs;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      grid.emplace_back(i * (truth.frame_size.width - 1) / 4.0, j * (truth.frame_size.height - 1) / 4.0);
  for (const auto& f : s.frames) {
    std::vector<cv::Point2d> a, b;
    cv::perspectiveTransform(grid, a, cv::Mat(ToMatx(f.frame_to_patch)));
    cv::perspectiveTransform(grid, b, cv::Mat(gt[fs::path(f.source).filename().string()]));
    ours.insert(ours.end(), a.begin(), a.end());
    theirs.insert(theirs.end(), b.begin(), b.end());
  }
  cv::Mat fit = cv::findHomography(ours, theirs, 0);
  std::vector<cv::Point2d> mapped;
  cv::perspectiveTransform(ours, mapped, fit);
  double sse = 0;
  for (size_t i = 0; i < mapped.size(); ++i) sse += std::pow(cv::norm(mapped[i] - theirs[i]), 2);
  return std::sqrt(sse / mapped.size());
}

TEST(Mosaicker, StitchesASyntheticSurveyWhereTheGroundTruthSays) {
  test::ScratchDir dir;
  Survey survey = WriteSurvey(test::SmallSurvey(24), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicSummary sum = MosaicInput(dir / "survey/frames", store, FastOptions());
  EXPECT_EQ(sum.frames, 24);
  EXPECT_EQ(sum.stitched, 24);
  EXPECT_EQ(sum.patches, 1);
  Store reopened = Store::Open(dir / "s.rolamos");
  ASSERT_EQ(reopened.patches().size(), 1u);
  PatchSidecar s = reopened.ReadSidecar(1);
  EXPECT_EQ(s.n_images, 24);
  EXPECT_LT(PatchRmsError(s, survey), 1.0);
  // The patch image holds every frame: opaque where frames were, and as large as the sidecar says.
  TiledImage image = TiledImage::Open(reopened.PatchImagePath(1), std::make_shared<TileCache>());
  EXPECT_EQ(image.width(), s.size[0]);
  EXPECT_TRUE(image.info().has_alpha);
  cv::Vec3d c = ToMatx(s.frames[12].frame_to_patch) * cv::Vec3d(240, 180, 1);
  cv::Mat px = image.ReadRegion(0, cv::Rect(int(c[0] / c[2]) - 2, int(c[1] / c[2]) - 2, 4, 4));
  EXPECT_EQ(cv::mean(px)[3], 255.0);
  ASSERT_TRUE(s.frames[5].egomotion.has_value());
  // The image is where the sidecar says: the patch, seen back through frame 12's homography,
  // shows frame 12 (at its centre, where its own weight dominates the blend).
  cv::Mat whole = image.ReadRegion(0, cv::Rect(0, 0, static_cast<int>(image.width()), static_cast<int>(image.height())));
  cv::Mat seen;
  cv::warpPerspective(whole, seen, cv::Mat(ToMatx(s.frames[12].frame_to_patch)), cv::Size(480, 360),
                      cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
  cv::Mat frame = cv::imread(dir / ("survey/" + survey.frames[12].file));
  cv::cvtColor(seen, seen, cv::COLOR_BGRA2BGR);
  const cv::Rect centre(140, 105, 200, 150);
  EXPECT_GT(test::PsnrAfterColourFit(seen(centre), frame(centre)), 32.0);  // 29.4 if off by 2 px
}

// The links the store keeps for `align` (patches/NNNNNN.links.json): each link's pixels are where
// the two frames' placements put the same ground, and a link keeps up to kMaxStoredLinkPairs of
// them (48 before session 53, which the chain's links now pass).
TEST(Mosaicker, TheStoredLinksHoldPixelsWhereThePlacementsPutTheSameGround) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(24), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, FastOptions());
  Store reopened = Store::Open(dir / "s.rolamos");
  ASSERT_EQ(reopened.patches().size(), 1u);
  const PatchSidecar s = reopened.ReadSidecar(1);
  ASSERT_TRUE(s.frame_links.has_value());
  std::map<int, cv::Matx33d> placed;
  for (const auto& f : s.frames) placed[f.index] = ToMatx(f.frame_to_patch);
  const std::vector<StoredLink> links = ReadFrameLinks((fs::path(dir / "s.rolamos") / *s.frame_links).string());
  ASSERT_GE(links.size(), 23u);  // at least the chain from frame to frame
  size_t most = 0;
  std::vector<double> apart;
  for (const auto& l : links) {
    ASSERT_EQ(l.in_a.size(), l.in_b.size());
    EXPECT_LE(l.in_a.size(), size_t(kMaxStoredLinkPairs));
    most = std::max(most, l.in_a.size());
    ASSERT_TRUE(placed.count(l.a.index) && placed.count(l.b.index));
    for (size_t i = 0; i < l.in_a.size(); ++i) {
      const cv::Vec3d pa = placed[l.a.index] * cv::Vec3d(l.in_a[i].x, l.in_a[i].y, 1);
      const cv::Vec3d pb = placed[l.b.index] * cv::Vec3d(l.in_b[i].x, l.in_b[i].y, 1);
      apart.push_back(std::hypot(pa[0] / pa[2] - pb[0] / pb[2], pa[1] / pa[2] - pb[1] / pb[2]));
    }
  }
  EXPECT_GT(most, 48u);
  std::nth_element(apart.begin(), apart.begin() + long(apart.size() / 2), apart.end());
  EXPECT_LT(apart[apart.size() / 2], 0.5);
}

// The summary's stages account for the run's CPU: the patch images' tiles, compressed on their
// own threads, are a stage of their own, and no stage is counted twice (they add up to no more
// than the process used).
TEST(Mosaicker, TheStagesAccountForTheRunsCpu) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(24), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  const MosaicSummary sum = MosaicInput(dir / "survey/frames", store, FastOptions());
  std::map<std::string, double> stage(sum.stage_seconds.begin(), sum.stage_seconds.end());
  ASSERT_EQ(stage.size(), sum.stage_seconds.size());  // each named once
  EXPECT_GT(stage["tile encoding"], 0);
  EXPECT_GT(stage["patch writing"], 0);
  EXPECT_GT(stage["features"], 0);
  double named = 0;
  for (const auto& [name, seconds] : sum.stage_seconds) named += seconds;
  EXPECT_LE(named, sum.cpu_seconds);
  EXPECT_NEAR(sum.RestCpuSeconds(), sum.cpu_seconds - named, 1e-9);  // what the CLI prints as `rest`
  EXPECT_NE(std::find(sum.keyframe_stages.begin(), sum.keyframe_stages.end(), "tile encoding"),
            sum.keyframe_stages.end());
}

// Ctrl-C on `rolamos mosaic FOLDER`: the stop ends the run as the end of the input would. The
// frames read by then are mapped and in the store's patches, the open patch written; none after.
TEST(Mosaicker, AStopEndsTheRunWithTheFramesReadInTheStore) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(40), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o = FastOptions();
  o.mask.clear();  // the overlay search would read the first 24 frames before any is mapped
  std::atomic<bool> stop{false};
  int reported = 0, total = 0;
  const MosaicSummary sum = MosaicInput(
      dir / "survey/frames", store, o,
      [&](const FrameReport&, int n) {
        total = n;
        if (++reported == 10) stop = true;
      },
      &stop);
  EXPECT_TRUE(sum.stopped);
  EXPECT_EQ(total, 40);
  // The frames already read (one more than the cores are prepared ahead of the engine) are
  // mapped, no more.
  EXPECT_GE(sum.frames, 10);
  EXPECT_LE(sum.frames, 10 + static_cast<int>(std::thread::hardware_concurrency()) + 1);
  EXPECT_LT(sum.frames, 40);
  EXPECT_EQ(sum.frames, reported);
  EXPECT_EQ(sum.stitched + sum.rejected, sum.frames);
  Store reopened = Store::Open(dir / "s.rolamos");
  int in_patches = 0;
  for (const auto& p : reopened.patches()) in_patches += static_cast<int>(reopened.ReadSidecar(p.id).frames.size());
  EXPECT_EQ(in_patches, sum.stitched);
  // Not stopped: every frame, and the summary does not say stopped.
  Store whole = Store::Create(dir / "whole.rolamos");
  std::atomic<bool> never{false};
  const MosaicSummary all = MosaicInput(dir / "survey/frames", whole, o, nullptr, &never);
  EXPECT_FALSE(all.stopped);
  EXPECT_EQ(all.frames, 40);
}

TEST(Mosaicker, AStopDuringTheOverlaySearchReadsNoMoreFrames) {
  // The overlay search reads the first 24 frames before any is mapped (72 past unreadable ones):
  // a stop there ends the run as well, with nothing read after it.
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(40), dir / "survey");
  MosaickerOptions o = FastOptions();
  o.mask = "auto";
  std::atomic<bool> stop{true};
  const MosaicSummary sum = MosaicInput(dir / "survey/frames", Store::Create(dir / "s.rolamos"), o, nullptr, &stop);
  EXPECT_TRUE(sum.stopped);
  EXPECT_EQ(sum.frames, 0);
  EXPECT_TRUE(Store::Open(dir / "s.rolamos").patches().empty());
}

// Two engines into one store numbered their patches from what it held when each began, and
// overwrote each other's; align and compose rewrote the manifest under an engine. While an engine
// writes, a second one, align and compose are refused; after it, the next engine goes on.
TEST(Mosaicker, OneEngineWritesAStoreAtATime) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(12), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  Mosaicker first(store, FastOptions());
  try {
    Mosaicker second(Store::Open(dir / "s.rolamos"), FastOptions());
    FAIL() << "a second engine was let into a store being written";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("is being written by a rolamos mosaic engine (pid "), std::string::npos)
        << e.what();
  }
  // Nor may align rewrite the sidecars and the manifest under it.
  try {
    AlignStore(Store::Open(dir / "s.rolamos"), AlignOptions{});
    FAIL() << "align was let into a store being written";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("is being written by a rolamos mosaic engine"), std::string::npos) << e.what();
  }
  // Nor compose record its placements in it.
  try {
    ComposeMosaic(Store::Open(dir / "s.rolamos"), ComposeOptions{});
    FAIL() << "compose was let into a store being written";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("is being written by a rolamos mosaic engine"), std::string::npos) << e.what();
  }
  first.Finish();
  EXPECT_NO_THROW(Mosaicker(Store::Open(dir / "s.rolamos"), FastOptions())) << "the first has let go";
}

TEST(Mosaicker, PixelBudgetClosesPatchesAndLinksThem) {
  test::ScratchDir dir;
  Survey survey = WriteSurvey(test::SmallSurvey(30), dir / "survey");
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : survey.frames) gt[fs::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o = FastOptions();
  o.patch_megapixels = 0.4;  // about two frames' worth of canvas
  MosaicSummary sum = MosaicInput(dir / "survey/frames", store, o);
  EXPECT_EQ(sum.stitched, 30);
  EXPECT_GE(sum.patches, 3);
  Store reopened = Store::Open(dir / "s.rolamos");
  int images = 0;
  PatchSidecar previous;
  for (const auto& p : reopened.patches()) {
    PatchSidecar s = reopened.ReadSidecar(p.id);
    EXPECT_LE(s.size[0] * s.size[1], 400000) << "patch " << p.id;
    images += s.n_images;
    if (p.id > 1) {
      ASSERT_TRUE(s.link.has_value()) << "patch " << p.id;
      EXPECT_EQ(s.link->previous_patch, p.id - 1);
      // The link maps this patch's pixels to the previous patch's: this patch's first frame
      // lands where ground truth says it lies relative to the previous patch's last frame.
      const std::array<double, 9> l = s.link->to_previous;
      const auto name = [](const FrameRecord& f) { return fs::path(f.source).filename().string(); };
      const cv::Matx33d first_to_last = gt[name(previous.frames.back())].inv() * gt[name(s.frames.front())];
      const cv::Matx33d ours = ToMatx(l) * ToMatx(s.first_homography);
      const cv::Matx33d truth = ToMatx(previous.last_homography) * first_to_last;
      for (const cv::Vec3d& p0 : {cv::Vec3d(0, 0, 1), cv::Vec3d(479, 359, 1), cv::Vec3d(240, 180, 1)}) {
        cv::Vec3d a = ours * p0, b = truth * p0;
        EXPECT_LT(std::hypot(a[0] / a[2] - b[0] / b[2], a[1] / a[2] - b[1] / b[2]), 3.0) << "patch " << p.id;
      }
    }
    previous = s;
  }
  EXPECT_EQ(images, 30);
  EXPECT_EQ(reopened.global().n_images, 30);
}

// A budget under a frame's pixels (5 Mpx against a 3840 x 2160 camera's 8.3) closed a patch at
// every keyframe: patches of one frame, nothing for the adjustment. A patch holds at least two
// frames' worth; the budget it was built under is what the sidecar says.
TEST(Mosaicker, APatchBudgetUnderAFramesPixelsStillHoldsSeveralFrames) {
  test::ScratchDir dir;
  Survey survey = WriteSurvey(test::SmallSurvey(16), dir / "survey");
  const long long frame = static_cast<long long>(survey.frame_size.area());
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o = FastOptions();
  o.patch_megapixels = 0.1;  // 480 x 360 frames: 0.17 Mpx each
  ASSERT_LT(o.patch_megapixels * 1e6, frame);
  EXPECT_EQ(o.PixelBudget(survey.frame_size), 2 * frame);
  EXPECT_EQ(o.PixelBudget(), 100000);
  MosaicSummary sum = MosaicInput(dir / "survey/frames", store, o);
  EXPECT_EQ(sum.stitched, 16);
  EXPECT_LT(sum.patches, sum.keyframes / 2 + 1);
  Store reopened = Store::Open(dir / "s.rolamos");
  for (const auto& p : reopened.patches()) {
    const PatchSidecar s = reopened.ReadSidecar(p.id);
    ASSERT_TRUE(s.pixel_budget.has_value());
    EXPECT_EQ(*s.pixel_budget, 2 * frame) << "patch " << p.id;
    EXPECT_LE(static_cast<long long>(s.size[0]) * s.size[1], 2 * frame) << "patch " << p.id;
  }
  // An explicit memory bound still holds: 16 bytes a pixel of 1 MiB is 65,536 pixels.
  o.patch_memory_mb = 1;
  EXPECT_EQ(o.PixelBudget(survey.frame_size), 65536);
}

// MosaicInput prepares several frames at once on worker threads; pushing the same frames one by
// one on this thread must give the same patches, frame for frame.
TEST(Mosaicker, ParallelPreparationGivesWhatPushingInOrderGives) {
  test::ScratchDir dir;
  Survey survey = WriteSurvey(test::SmallSurvey(20), dir / "survey");
  MosaickerOptions o = FastOptions();
  o.patch_megapixels = 0.6;  // several patches, so closing and linking are covered too
  Store parallel = Store::Create(dir / "parallel.rolamos");
  MosaicSummary a = MosaicInput(dir / "survey/frames", parallel, o);
  Store sequential = Store::Create(dir / "sequential.rolamos");
  {
    Mosaicker m(sequential, o);
    for (const auto& f : survey.frames) {
      const std::string path = dir / ("survey/" + f.file);
      m.Push(cv::imread(path), path);
    }
    m.Finish();
  }
  Store p2 = Store::Open(dir / "parallel.rolamos"), s2 = Store::Open(dir / "sequential.rolamos");
  ASSERT_GE(a.patches, 2);
  ASSERT_EQ(p2.patches().size(), s2.patches().size());
  for (size_t i = 0; i < p2.patches().size(); ++i) {
    const PatchSidecar x = p2.ReadSidecar(p2.patches()[i].id), y = s2.ReadSidecar(s2.patches()[i].id);
    ASSERT_EQ(x.frames.size(), y.frames.size()) << "patch " << i;
    for (size_t k = 0; k < x.frames.size(); ++k) {
      EXPECT_EQ(fs::path(x.frames[k].source).filename(), fs::path(y.frames[k].source).filename());
      for (size_t e = 0; e < 9; ++e)
        EXPECT_NEAR(x.frames[k].frame_to_patch[e], y.frames[k].frame_to_patch[e], 1e-9)
            << "patch " << i << " frame " << k;
    }
  }
}

TEST(Mosaicker, BadFramesAreRejectedWithReasonsAndPatchesStayValid) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(12), dir / "survey");
  const std::string frames = dir / "survey/frames";
  // Frame 4 truncated, frame 6 another size, frame 8 featureless sand (flat), then a text file.
  const std::string f4 = frames + "/frame_00004.jpg";
  fs::resize_file(f4, fs::file_size(f4) / 3);
  cv::imwrite(frames + "/frame_00006.jpg", cv::Mat(200, 300, CV_8UC3, cv::Scalar(90, 120, 100)));
  cv::imwrite(frames + "/frame_00008.jpg", cv::Mat(360, 480, CV_8UC3, cv::Scalar(90, 120, 100)));
  std::ofstream(frames + "/frame_00009.jpg") << "not a jpeg";
  Store store = Store::Create(dir / "s.rolamos");
  std::vector<FrameReport> reports;
  MosaicSummary sum = MosaicInput(frames, store, FastOptions(),
                                  [&](const FrameReport& r, int) { reports.push_back(r); });
  ASSERT_EQ(reports.size(), 12u);
  EXPECT_EQ(reports[6].status, "rejected");
  EXPECT_NE(reports[6].reason.find("size_changed"), std::string::npos);
  EXPECT_EQ(reports[8].reason, "featureless");
  EXPECT_NE(reports[9].reason.find("unreadable"), std::string::npos);
  EXPECT_NE(reports[4].reason.find("truncated"), std::string::npos);
  EXPECT_EQ(sum.stitched, 8);  // every good frame
  Store reopened = Store::Open(dir / "s.rolamos");
  int rejected = 0;
  for (const auto& p : reopened.patches()) rejected += static_cast<int>(reopened.ReadSidecar(p.id).rejected.size());
  EXPECT_EQ(rejected, sum.rejected);
  // The summary lists them too, in the input's order, with the reasons the reports gave.
  ASSERT_EQ(static_cast<int>(sum.rejected_frames.size()), sum.rejected);
  for (size_t i = 0; i < sum.rejected_frames.size(); ++i) {
    const RejectedFrame& r = sum.rejected_frames[i];
    if (i > 0) EXPECT_LT(sum.rejected_frames[i - 1].index, r.index);
    EXPECT_EQ(reports[size_t(r.index)].status, "rejected") << r.source;
    EXPECT_EQ(reports[size_t(r.index)].reason, r.reason) << r.source;
  }
}

TEST(Mosaicker, ReadsVideoAndFrameLists) {
  test::ScratchDir dir;
  Survey survey = WriteSurvey(test::SmallSurvey(16), dir / "survey");
  // The same frames as a video (Motion-JPEG in AVI, which OpenCV writes without extra codecs)...
  cv::VideoWriter video(dir / "dive.avi", cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10,
                        survey.frame_size);
  if (!video.isOpened()) GTEST_SKIP() << "this OpenCV cannot write AVI";
  std::ofstream list(dir / "frames.txt");
  for (const auto& f : survey.frames) {
    video.write(cv::imread(dir / ("survey/" + f.file)));
    list << "survey/" << f.file << "\n";
  }
  video.release();
  list.close();
  // A video codec's frames are followed halved (track_halve "auto"), stills at full size, when
  // the frame holds no more than track_pixels and at least 0.4 of it.
  MosaickerOptions o = FastOptions();
  o.track_pixels = 0.3e6;
  Store from_video = Store::Create(dir / "v.rolamos");
  MosaicSummary v = MosaicInput(dir / "dive.avi", from_video, o);
  EXPECT_EQ(v.frames, 16);
  EXPECT_GE(v.stitched, 15);
  EXPECT_EQ(v.track_scale, 0.5);
  EXPECT_EQ(Store::Open(dir / "v.rolamos").ReadSidecar(1).frames[3].source, "dive.avi#3");
  // ...and as a list of files relative to the list.
  Store from_list = Store::Create(dir / "l.rolamos");
  MosaicSummary l = MosaicInput(dir / "frames.txt", from_list, o);
  EXPECT_EQ(l.stitched, 16);
  EXPECT_EQ(l.track_scale, 1.0);
  // Asked for, either way whatever the input.
  o.track_halve = "never";
  Store video_full = Store::Create(dir / "vf.rolamos");
  EXPECT_EQ(MosaicInput(dir / "dive.avi", video_full, o).track_scale, 1.0);
  o.track_halve = "always";
  Store list_halved = Store::Create(dir / "lh.rolamos");
  EXPECT_EQ(MosaicInput(dir / "frames.txt", list_halved, o).track_scale, 0.5);
  // A video's frames go on down to video_track_pixels (1292 x 964 video at a quarter by default;
  // these small frames when asked); stills do not.
  o.track_halve = "auto";
  o.video_track_pixels = 0.03e6;
  Store video_quarter = Store::Create(dir / "vq.rolamos");
  const MosaicSummary q = MosaicInput(dir / "dive.avi", video_quarter, o);
  EXPECT_EQ(q.track_scale, 0.25);
  EXPECT_GE(q.stitched, 15);
  Store list_full = Store::Create(dir / "lf.rolamos");
  EXPECT_EQ(MosaicInput(dir / "frames.txt", list_full, o).track_scale, 1.0);
}

TEST(Mosaicker, AutoCalibrationIsEstimatedAndKeptInTheStore) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(10), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o = FastOptions();
  o.calibration = "auto";
  MosaicSummary sum = MosaicInput(dir / "survey/frames", store, o);
  EXPECT_EQ(sum.stitched, 10);
  EXPECT_NE(sum.calibration_note.find("k1 = "), std::string::npos);
  EXPECT_TRUE(fs::exists(dir / "s.rolamos/calibration.yml"));
  // Mosaicker alone has no frames to estimate from: a clear error, not a guess.
  EXPECT_THROW(Mosaicker(store, o), Error);
  // These frames have no distortion: the frames are mapped as they are, the focal length
  // estimated from the field of view as without a file (the file's 0.9 x width was held, and
  // the frames resampled through a map that moved nothing: 0.32 -> 0.53 px on lawn-noturn).
  ASSERT_NE(sum.calibration_note.find("k1 = 0.000"), std::string::npos) << sum.calibration_note;
  Store plain = Store::Create(dir / "plain.rolamos");
  o.calibration.clear();
  MosaicInput(dir / "survey/frames", plain, o);
  const Store a = Store::Open(dir / "s.rolamos"), b = Store::Open(dir / "plain.rolamos");
  ASSERT_EQ(a.patches().size(), b.patches().size());
  for (const auto& p : a.patches()) {
    const PatchSidecar x = a.ReadSidecar(p.id), y = b.ReadSidecar(p.id);
    ASSERT_EQ(x.frames.size(), y.frames.size());
    for (size_t i = 0; i < x.frames.size(); ++i)
      for (int k = 0; k < 9; ++k) EXPECT_NEAR(x.frames[i].frame_to_patch[k], y.frames[i].frame_to_patch[k], 1e-9);
  }
}

// A camera-rate video's consecutive frames barely move: distortion does not show between them,
// and self-calibration found none (k1 = 0 on a 90-degree lens, and a map hundreds of pixels off).
// From a video the frames are taken a quarter of the frame apart.
TEST(Mosaicker, AutoCalibrationFindsTheLensOfACameraRateVideo) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(70);
  so.fov_deg = 90;
  so.k1 = -0.08;
  so.forward_overlap = 0.95;
  so.lanes = 1;
  so.video = "video.mp4";
  WriteSurvey(so, dir / "survey");
  MosaickerOptions o = FastOptions();
  o.calibration = "auto";
  const MosaicSummary sum = MosaicInput(dir / "survey/video.mp4", Store::Create(dir / "s.rolamos"), o);
  EXPECT_EQ(sum.stitched, 70);
  // The survey's k1 at the focal length self-calibration assumes (0.9 x the width, 432 px)
  // against the lens's (240 px): -0.08 x (432 / 240)^2 = -0.26.
  const size_t at = sum.calibration_note.find("k1 = ");
  ASSERT_NE(at, std::string::npos) << sum.calibration_note;
  EXPECT_NEAR(std::stod(sum.calibration_note.substr(at + 5)), -0.26, 0.06) << sum.calibration_note;
  // And on clear evidence: frames apart, the lens taken out, many more matches agree with one
  // homography (consecutive frames: 6156 -> 6189, a guess the next survey may not allow).
  int before = 0, after = 0;
  ASSERT_EQ(std::sscanf(sum.calibration_note.c_str() + sum.calibration_note.find("inliers "), "inliers %d -> %d",
                        &before, &after), 2) << sum.calibration_note;
  EXPECT_GT(after, before + before / 5) << sum.calibration_note;
}

TEST(Mosaicker, ImpossibleOptionsAndInputsAreRefused) {
  test::ScratchDir dir;
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o;
  o.features = "surf";
  EXPECT_THROW(Mosaicker(store, o), Error);
  o = MosaickerOptions{};
  o.patch_megapixels = 0;
  EXPECT_THROW(Mosaicker(store, o), Error);
  o = MosaickerOptions{};
  o.blend_overlap = 0;
  EXPECT_NE(test::ErrorOf([&] { Mosaicker(store, o); }).find("blend overlap"), std::string::npos);
  o = MosaickerOptions{};
  o.track_halve = "sometimes";
  EXPECT_NE(test::ErrorOf([&] { Mosaicker(store, o); }).find("\"sometimes\" is none of auto, always, never"),
            std::string::npos);
  o = MosaickerOptions{};
  o.calibration = dir / "missing.yml";
  EXPECT_THROW(Mosaicker(store, o), Error);
  EXPECT_THROW(MosaicInput(dir / "nothing-here", store, MosaickerOptions{}), Error);
  std::ofstream(dir / "clip.mp4") << "not a video";
  EXPECT_THROW(MosaicInput(dir / "clip.mp4", store, MosaickerOptions{}), Error);
}

}  // namespace
}  // namespace rolamos
