#include "rolamos/global_align.hpp"

#include <filesystem>

#include <gtest/gtest.h>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/survey.hpp"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

double GlobalRms(const Store& store, const Survey& truth, bool aligned) {
  return test::Rms(test::ErrorsAgainstTruth(store, truth, aligned));
}

// A lawnmower survey whose lanes overlap: loop closure must find the revisits and bring the whole
// map closer to the ground truth than the chain of online placements; compose then uses it.
TEST(AlignStore, LoopClosureReducesGlobalDriftOnALawnmowerSurvey) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(72), dir / "survey");
  Store store = test::MosaicAndCompose(dir / "survey/frames", dir / "s.rolamos", 0.8);
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  const double before = GlobalRms(store, survey, false);

  // Loops that close within the threshold are left alone.
  AlignOptions strict;
  strict.min_loop_error_px = 1000;
  const AlignSummary skipped = AlignStore(store, strict);
  EXPECT_FALSE(skipped.corrected);
  EXPECT_FALSE(store.ReadSidecar(store.patches().front().id).aligned.has_value());
  // By default the neighbouring lanes are found (frames apart in time), and they show the drift.
  const AlignOptions all;
  const AlignSummary r = AlignStore(store, all);
  EXPECT_TRUE(r.corrected);
  EXPECT_EQ(r.frames, 72);
  EXPECT_GT(r.pairs_found, 10);
  EXPECT_LT(r.loop_error_after_px, r.loop_error_before_px);
  const double after = GlobalRms(store, survey, true);
  EXPECT_LT(after, before) << "before " << before << " px";
  EXPECT_LT(after, 2.0) << "before " << before << " px";
  // Online placements kept; compose draws the aligned one.
  for (const auto& p : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(p.id);
    EXPECT_TRUE(s.patch_to_global_online.has_value());
    EXPECT_TRUE(s.aligned.value_or(false));
  }
  EXPECT_GT(ComposeMosaic(store, co).patches_used, 1);
  // Aligning again starts from the online placements: the same result.
  AlignStore(store, all);
  EXPECT_NEAR(GlobalRms(store, survey, true), after, 1e-6);
}

// Navigation from the ground truth (2 mm a texture pixel): the frames pulled towards it end up
// closer to the truth than the online chain (1.03 -> 0.59 px here), and the navigation fits them
// better. The first frame of this survey is tilted, so the online frame is in perspective.
TEST(AlignStore, NavigationPullsTheFramesToTheMap) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(48), dir / "survey");
  Store store = test::MosaicAndCompose(dir / "survey/frames", dir / "s.rolamos");
  const double before = GlobalRms(store, survey, false);
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
    o.navigation[std::filesystem::path(f.file).filename().string()] = n;
  }
  const AlignSummary r = AlignStore(store, o);
  EXPECT_TRUE(r.corrected);
  EXPECT_EQ(r.navigation_frames, 48);
  EXPECT_LT(r.navigation_after_m, r.navigation_before_m);
  const double after = GlobalRms(store, survey, true);
  EXPECT_LT(after, before);
  EXPECT_LT(after, 0.8 * before) << "before " << before << " px";
  // Navigation for none of these frames is a clear error, not a silent no-op.
  AlignOptions wrong;
  wrong.navigation["someone-else.jpg"] = o.navigation.begin()->second;
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, wrong); }).find("navigation"), std::string::npos);
}

TEST(AlignStore, ClearErrorsBeforeComposeAndForMissingFrames) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(16), dir / "survey");
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, mo);
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, AlignOptions{}); }).find("rolamos compose"), std::string::npos);
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  ComposeMosaic(store, co);
  AlignOptions o;
  o.frames_dir = dir / "elsewhere";
  o.search_radius = 3;  // so that some pair is tried and its frames are needed
  o.min_index_gap = 2;
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, o); }).find("frames_dir"), std::string::npos);
  o = AlignOptions{};
  o.model = "projective";
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, o); }).find("projective"), std::string::npos);
}

}  // namespace
}  // namespace rolamos
