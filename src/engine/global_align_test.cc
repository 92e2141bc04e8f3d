#include "rolamos/align.hpp"

#include <filesystem>
#include <map>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/synth.hpp"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

// Every stitched frame's 3 x 3 grid in the global frame against ground truth, after one best-fit
// homography for the whole map: RMS pixels. `aligned` reads the frames' frame_to_global.
double GlobalRms(const Store& store, const Survey& truth, bool aligned) {
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : truth.frames) gt[fs::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  std::vector<cv::Point2d> ours, theirs;
  for (const auto& p : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(p.id);
    const Homography online = s.extra.contains("patch_to_global_online") ? s.extra["patch_to_global_online"].get<Homography>()
                                                                           : *s.patch_to_global;
    for (const auto& f : s.frames) {
      const cv::Matx33d H = aligned ? ToMatx(f.extra.at("frame_to_global").get<Homography>())
                                    : ToMatx(online) * ToMatx(f.frame_to_patch);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const cv::Vec3d p(i * (truth.frame_size.width - 1) / 2.0, j * (truth.frame_size.height - 1) / 2.0, 1);
          const cv::Vec3d a = H * p, b = gt[fs::path(f.source).filename().string()] * p;
          ours.emplace_back(a[0] / a[2], a[1] / a[2]);
          theirs.emplace_back(b[0] / b[2], b[1] / b[2]);
        }
    }
  }
  const cv::Mat fit = cv::findHomography(ours, theirs, 0);
  std::vector<cv::Point2d> mapped;
  cv::perspectiveTransform(ours, mapped, fit);
  double sse = 0;
  for (size_t i = 0; i < mapped.size(); ++i) sse += std::pow(cv::norm(mapped[i] - theirs[i]), 2);
  return std::sqrt(sse / mapped.size());
}

// A lawnmower survey whose lanes overlap: loop closure must find the revisits and bring the whole
// map closer to the ground truth than the chain of online placements; compose then uses it.
TEST(AlignStore, LoopClosureReducesGlobalDriftOnALawnmowerSurvey) {
  test::ScratchDir dir;
  SurveyOptions so;
  so.frame_width = 480;
  so.frame_height = 360;
  so.focal_px = 420;
  so.frames = 72;
  const Survey survey = WriteSurvey(so, dir / "survey");
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
  SurveyOptions so;
  so.frame_width = 480;
  so.frame_height = 360;
  so.focal_px = 420;
  so.frames = 16;
  WriteSurvey(so, dir / "survey");
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
