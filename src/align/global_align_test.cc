#include "rolamos/global_align.hpp"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/survey.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"
#include "util/files.h"
#include "util/homography.h"

namespace fs = std::filesystem;

namespace rolamos {
namespace {

double GlobalRms(const Store& store, const Survey& truth, bool aligned) {
  return test::Rms(test::ErrorsAgainstTruth(store, truth, aligned));
}

MosaickerOptions Fast(double patch_megapixels = 0) {
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  if (patch_megapixels > 0) mo.patch_megapixels = patch_megapixels;
  return mo;
}

ComposeOptions FastCompose() {
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  return co;
}

// Lanes that join turned 180 degrees, and roll and pitch jittered per frame: the lanes overlap
// side by side, which only loop closure can tie together. Every frame goes into one map, closer to
// the truth than the engine's links alone can place it.
TEST(AlignStore, OneMapOfTheWholeSurveyFromLinksRetrievalAndLoops) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(60);
  so.fov_deg = 60;
  so.lanes = 4;
  so.lane_turns = false;
  so.attitude_jitter_deg = 0.7;
  so.forward_overlap = 0.7;
  so.side_overlap = 0.4;
  const Survey survey = WriteSurvey(so, dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast(0.5));  // several patches
  // No compose first: align places every patch itself.
  const AlignSummary r = AlignStore(store, AlignOptions{});
  EXPECT_EQ(r.frames, 60);
  EXPECT_EQ(r.components, 1);
  EXPECT_GT(r.online_edges, 59);
  EXPECT_GT(r.loop_edges + r.retrieval_edges, 10);
  EXPECT_LT(r.rms_after_px, 1.5);
  Store reopened = Store::Open(dir / "s.rolamos");
  for (const auto& p : reopened.patches()) {
    const PatchSidecar s = reopened.ReadSidecar(p.id);
    EXPECT_TRUE(s.aligned.value_or(false));
    EXPECT_EQ(s.component.value_or(-1), 0);
    for (const auto& f : s.frames) EXPECT_TRUE(f.frame_to_global.has_value());
  }
  const double aligned = GlobalRms(reopened, survey, true);
  EXPECT_LT(aligned, 1.5) << "global RMS after align";
  // compose draws every frame where align put it.
  const ComposeResult c = ComposeMosaic(reopened, FastCompose());
  EXPECT_TRUE(c.left_out.empty());
  EXPECT_EQ(c.patches_used, static_cast<int>(reopened.patches().size()));
  // The mosaic, seen back through a frame's own placement, shows that frame.
  {
    const Store composed = Store::Open(dir / "s.rolamos");
    TiledImage mosaic = TiledImage::Open(composed.MosaicPath(), std::make_shared<TileCache>());
    const PatchSidecar s = composed.ReadSidecar(composed.patches()[1].id);
    const FrameRecord& f = s.frames[s.frames.size() / 2];
    const cv::Matx33d F = ToMatx(*f.frame_to_global);
    const cv::Rect2d b = WarpedBounds(F, survey.frame_size);
    const cv::Rect area = cv::Rect(int(b.x), int(b.y), int(b.width) + 2, int(b.height) + 2) &
                          cv::Rect(0, 0, int(mosaic.width()), int(mosaic.height()));
    const cv::Mat part = mosaic.ReadRegion(0, area);
    cv::Mat seen;
    cv::warpPerspective(part, seen, cv::Mat(cv::Matx33d(1, 0, -area.x, 0, 1, -area.y, 0, 0, 1) * F), survey.frame_size,
                        cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
    cv::cvtColor(seen, seen, cv::COLOR_BGRA2BGR);
    const cv::Mat frame = cv::imread(dir / ("survey/frames/" + fs::path(f.source).filename().string()));
    const cv::Rect centre(140, 105, 200, 150);
    EXPECT_GT(test::PsnrAfterColourFit(seen(centre), frame(centre)), 30.0);  // a 2 px error gives ~29
  }
  // Aligning again gives the same map (align is repeatable).
  AlignStore(reopened, AlignOptions{});
  EXPECT_NEAR(GlobalRms(Store::Open(dir / "s.rolamos"), survey, true), aligned, 0.05);
}

// Open water in mid-survey: two parts that share no ground become two components, placed side by
// side, both composed; nothing is left out.
TEST(AlignStore, PartsThatShareNoGroundAreComponentsSideBySide) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(36);
  so.lanes = 1;
  WriteSurvey(so, dir / "survey");
  for (int i = 14; i <= 21; ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "/frame_%05d.jpg", i);
    cv::imwrite(dir / ("survey/frames" + std::string(name)), cv::Mat(360, 480, CV_8UC3, cv::Scalar(70, 60, 20)));
  }
  Store store = Store::Create(dir / "s.rolamos");
  const MosaicSummary m = MosaicInput(dir / "survey/frames", store, Fast());
  const AlignSummary r = AlignStore(store, AlignOptions{});
  EXPECT_EQ(r.frames, m.stitched);
  EXPECT_EQ(r.components, 2);
  ASSERT_EQ(r.component_frames.size(), 2u);
  EXPECT_EQ(r.component_frames[0] + r.component_frames[1], m.stitched);
  const ComposeResult c = ComposeMosaic(Store::Open(dir / "s.rolamos"), FastCompose());
  EXPECT_TRUE(c.left_out.empty());
  EXPECT_EQ(c.patches_used, m.patches);
}

// The same ground planted in two places the survey never connects: appearance retrieval finds the
// pair, and it must not pull the two parts together or bend either.
TEST(AlignStore, AFalseLoopDoesNotBendTheMap) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(40);
  so.lanes = 2;
  const Survey survey = WriteSurvey(so, dir / "survey");
  // Frame 35 (second lane) replaced by a copy of frame 5 (first lane, elsewhere on the ground).
  fs::copy_file(dir / "survey/frames/frame_00005.jpg", dir / "survey/frames/frame_00035.jpg",
                fs::copy_options::overwrite_existing);
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast(0.5));
  const AlignSummary r = AlignStore(store, AlignOptions{});
  EXPECT_GE(r.frames, 38);
  // Every frame but the planted one where the truth says.
  const std::vector<double> e = test::ErrorsAgainstTruth(Store::Open(dir / "s.rolamos"), survey, true);
  std::vector<double> sorted = e;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_LT(sorted[sorted.size() * 9 / 10], 3.0);
}

// Navigation from the ground truth (2 mm a texture pixel): the camera centres are pulled towards
// it and the frames end up as close to the truth as vision puts them, or closer.
TEST(AlignStore, NavigationPullsTheCamerasToTheMap) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(48), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast());
  AlignOptions o;
  for (const auto& f : survey.frames) {
    // The frame's pixel -> map affine, linearised at its centre.
    const cv::Matx33d W = ToMatx(f.frame_to_world);
    const cv::Size s = survey.frame_size;
    const cv::Point2d c = ApplyHomography(W, {(s.width - 1) / 2.0, (s.height - 1) / 2.0});
    const cv::Point2d dx = ApplyHomography(W, {(s.width + 1) / 2.0, (s.height - 1) / 2.0}) - c;
    const cv::Point2d dy = ApplyHomography(W, {(s.width - 1) / 2.0, (s.height + 1) / 2.0}) - c;
    FrameNavigation n;
    n.crs = "EPSG:32755";
    const double m = 0.002;
    n.geotransform = {500000 + m * (c.x - dx.x * (s.width - 1) / 2.0 - dy.x * (s.height - 1) / 2.0), m * dx.x, m * dy.x,
                      5200000 - m * (c.y - dx.y * (s.width - 1) / 2.0 - dy.y * (s.height - 1) / 2.0), -m * dx.y, -m * dy.y};
    o.navigation[fs::path(f.file).filename().string()] = n;
  }
  o.navigation_sigma_m = 0.0005;  // a quarter of a pixel: finer than vision places these frames
  const AlignSummary r = AlignStore(store, o);
  EXPECT_EQ(r.navigation_frames, 48);
  EXPECT_LT(r.navigation_after_m, r.navigation_before_m) << r.navigation_before_m << " -> " << r.navigation_after_m;
  EXPECT_LT(GlobalRms(Store::Open(dir / "s.rolamos"), survey, true), 1.5);
  // Navigation for none of these frames is a clear error, not a silent no-op.
  AlignOptions wrong;
  wrong.navigation["someone-else.jpg"] = o.navigation.begin()->second;
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, wrong); }).find("navigation"), std::string::npos);
}

// Navigation that disagrees with vision for part of the survey (a bad fix, a jump of a metre) is
// discounted: the map keeps to the frames.
TEST(AlignStore, NavigationThatContradictsVisionForPartOfTheSurveyIsDiscounted) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(48), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast());
  AlignOptions o;
  for (const auto& f : survey.frames) {
    const cv::Matx33d W = ToMatx(f.frame_to_world);
    const cv::Size s = survey.frame_size;
    const cv::Point2d c = ApplyHomography(W, {(s.width - 1) / 2.0, (s.height - 1) / 2.0});
    const cv::Point2d dx = ApplyHomography(W, {(s.width + 1) / 2.0, (s.height - 1) / 2.0}) - c;
    const cv::Point2d dy = ApplyHomography(W, {(s.width - 1) / 2.0, (s.height + 1) / 2.0}) - c;
    FrameNavigation n;
    n.crs = "EPSG:32755";
    const double m = 0.002;
    const double jump = f.index >= 20 && f.index < 28 ? 1.0 : 0.0;  // eight frames a metre off
    n.geotransform = {500000 + jump + m * (c.x - dx.x * (s.width - 1) / 2.0 - dy.x * (s.height - 1) / 2.0), m * dx.x,
                      m * dy.x, 5200000 - m * (c.y - dx.y * (s.width - 1) / 2.0 - dy.y * (s.height - 1) / 2.0),
                      -m * dx.y, -m * dy.y};
    o.navigation[fs::path(f.file).filename().string()] = n;
  }
  o.navigation_sigma_m = 0.01;
  AlignStore(store, o);
  EXPECT_LT(GlobalRms(Store::Open(dir / "s.rolamos"), survey, true), 3.0);
}

// An align stopped half way (here by its progress callback; kill -9 in the CLI test) leaves the
// store exactly as it was: every sidecar the old one.
TEST(AlignStore, AnInterruptedAlignLeavesTheStoreAsItWas) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(24), dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast(0.5));
  const std::string before = ReadSmallFile(dir / "s.rolamos/store.json");
  EXPECT_THROW(AlignStore(store, AlignOptions{}, [](double f) {
                 if (f > 0.5) throw Error("stopped");
               }),
               Error);
  EXPECT_EQ(ReadSmallFile(dir / "s.rolamos/store.json"), before);
  Store reopened = Store::Open(dir / "s.rolamos");
  for (const auto& p : reopened.patches()) EXPECT_FALSE(reopened.ReadSidecar(p.id).aligned.has_value());
  // And the next align completes.
  AlignStore(reopened, AlignOptions{});
  EXPECT_TRUE(Store::Open(dir / "s.rolamos").ReadSidecar(1).aligned.value_or(false));
}

TEST(AlignStore, ClearErrorsForBadOptionsAndEmptyStores) {
  test::ScratchDir dir;
  Store empty = Store::Create(dir / "e.rolamos");
  EXPECT_NE(test::ErrorOf([&] { AlignStore(empty, AlignOptions{}); }).find("no patches"), std::string::npos);
  AlignOptions o;
  o.min_inliers = 3;
  EXPECT_NE(test::ErrorOf([&] { AlignStore(empty, o); }).find("inliers"), std::string::npos);
}

}  // namespace
}  // namespace rolamos

namespace rolamos {
namespace {

// Look-alike ground: the world's bottom-right quarter repeats its top-left quarter turned 180
// degrees, so frames over the two match by appearance at the wrong place, many of them agreeing
// on the same wrong offset. The map must come out as on a world without repetition: one part,
// within a pixel of the truth, the false set left out and reported; every frame's confidence
// written, and `rolamos info` naming where the map is least sure.
TEST(AlignStore, LookAlikeGroundDoesNotFoldTheMap) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(240);
  so.lanes = 8;
  so.lane_turns = false;
  so.repeat = "rotate";
  const Survey survey = WriteSurvey(so, dir / "survey");
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, Fast());
  const AlignSummary r = AlignStore(store, AlignOptions{});
  EXPECT_EQ(r.components, 1);
  EXPECT_GT(r.edges_inconsistent, 10) << "the repeated quarter matches the original one";
  ASSERT_FALSE(r.rejected_joins.empty());
  EXPECT_NE(r.rejected_joins[0].joined.find("frames"), std::string::npos);
  const double rms = GlobalRms(Store::Open(dir / "s.rolamos"), survey, true);
  EXPECT_LT(rms, 1.0) << "the map folded on look-alike ground";
  int with_confidence = 0, total = 0;
  for (const auto& p : store.patches())
    for (const auto& f : store.ReadSidecar(p.id).frames) {
      ++total;
      with_confidence += f.uncertainty_px.has_value() && f.residual_px.has_value() && f.align_edges.value_or(0) > 0;
    }
  EXPECT_EQ(with_confidence, total);
  const auto info = test::RunCli("info " + (dir / "s.rolamos"));
  EXPECT_NE(info.output.find("least sure"), std::string::npos) << info.output;
}

}  // namespace
}  // namespace rolamos
