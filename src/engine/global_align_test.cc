#include "rolamos/align.hpp"

#include <filesystem>

#include <gtest/gtest.h>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/synth.hpp"
#include "test_support.h"

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
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  mo.patch_megapixels = 0.8;
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, mo);
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  ComposeMosaic(store, co);
  const double before = GlobalRms(store, survey, false);

  // This survey's loops close to ~0.8 px: by default that is left alone.
  const AlignSummary skipped = AlignStore(store, AlignOptions{});
  EXPECT_FALSE(skipped.corrected);
  EXPECT_FALSE(store.ReadSidecar(store.patches().front().id).extra.contains("aligned"));
  AlignOptions all;
  all.min_loop_error_px = 0;  // correct anyway: the global error is larger than the loops show
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
    EXPECT_TRUE(s.extra.contains("patch_to_global_online"));
    EXPECT_TRUE(s.extra.value("aligned", false));
  }
  EXPECT_GT(ComposeMosaic(store, co).patches_used, 1);
  // Aligning again starts from the online placements: the same result.
  AlignStore(store, all);
  EXPECT_NEAR(GlobalRms(store, survey, true), after, 1e-6);
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
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, o); }).find("--frames"), std::string::npos);
  o = AlignOptions{};
  o.model = "projective";
  EXPECT_NE(test::ErrorOf([&] { AlignStore(store, o); }).find("projective"), std::string::npos);
}

}  // namespace
}  // namespace rolamos
