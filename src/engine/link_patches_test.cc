#include "rolamos/link_patches.hpp"

#include <filesystem>
#include <map>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/synth.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

// Two featureless frames lose the track: the engine starts an unlinked patch, compose leaves it
// out; place recognition finds where its first frame was seen and links it, and the composed
// mosaic then holds every frame where the ground truth says.
TEST(LinkPatches, RelinksAPatchAfterLostTrackingByItsFrames) {
  test::ScratchDir dir;
  SurveyOptions so;
  so.frame_width = 480;
  so.frame_height = 360;
  so.focal_px = 420;
  so.frames = 24;
  const Survey survey = WriteSurvey(so, dir / "survey");
  for (int k : {10, 11}) {
    char name[64];
    std::snprintf(name, sizeof name, "/survey/frames/frame_%05d.jpg", k);
    cv::imwrite(dir / name, cv::Mat(360, 480, CV_8UC3, cv::Scalar(90, 120, 100)));
  }
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  mo.max_lost_frames = 2;
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "survey/frames", store, mo);
  ASSERT_EQ(store.patches().size(), 2u);
  ASSERT_FALSE(store.ReadSidecar(2).extra.contains("link"));
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  EXPECT_EQ(ComposeMosaic(store, co).left_out.size(), 1u);

  const LinkSummary r = LinkPatches(store, LinkOptions{});
  ASSERT_EQ(r.linked.size(), 1u);
  EXPECT_EQ(r.linked[0], std::make_pair(2, 1));
  EXPECT_TRUE(r.unlinked.empty());
  const auto link = store.ReadSidecar(2).extra["link"];
  EXPECT_EQ(link["method"], "place_recognition");
  EXPECT_GE(link["inliers"].get<int>(), 40);
  const ComposeResult c = ComposeMosaic(store, co);
  EXPECT_EQ(c.patches_used, 2);
  EXPECT_TRUE(c.left_out.empty());
  // Every frame against the ground truth after one best-fit homography for the whole map.
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : survey.frames) gt[fs::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  std::vector<cv::Point2d> ours, theirs;
  for (const auto& p : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(p.id);
    for (const auto& f : s.frames)
      for (const cv::Vec3d& q : {cv::Vec3d(0, 0, 1), cv::Vec3d(479, 0, 1), cv::Vec3d(0, 359, 1), cv::Vec3d(479, 359, 1)}) {
        const cv::Vec3d a = ToMatx(*s.patch_to_global) * ToMatx(f.frame_to_patch) * q;
        const cv::Vec3d b = gt[fs::path(f.source).filename().string()] * q;
        ours.emplace_back(a[0] / a[2], a[1] / a[2]);
        theirs.emplace_back(b[0] / b[2], b[1] / b[2]);
      }
  }
  const cv::Mat fit = cv::findHomography(ours, theirs, 0);
  std::vector<cv::Point2d> mapped;
  cv::perspectiveTransform(ours, mapped, fit);
  double worst = 0;
  for (size_t i = 0; i < mapped.size(); ++i) worst = std::max(worst, cv::norm(mapped[i] - theirs[i]));
  EXPECT_LT(worst, 4.0);
}

// A patch whose frames match nothing before it stays unlinked, with the reason.
TEST(LinkPatches, ReportsWhatItCannotLink) {
  test::ScratchDir dir;
  SurveyOptions so;
  so.frame_width = 480;
  so.frame_height = 360;
  so.focal_px = 420;
  so.frames = 8;
  WriteSurvey(so, dir / "a");
  SeafloorTextureOptions other;
  other.seed = 4242;  // another stretch of seafloor altogether
  cv::imwrite(dir / "other.png", RenderSeafloor(0, 0, 2400, 2400, other));
  so.texture = dir / "other.png";
  WriteSurvey(so, dir / "b");
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  Store store = Store::Create(dir / "s.rolamos");
  MosaicInput(dir / "a/frames", store, mo);
  MosaicInput(dir / "b/frames", store, mo);
  const LinkSummary r = LinkPatches(store, LinkOptions{});
  EXPECT_TRUE(r.linked.empty());
  ASSERT_EQ(r.unlinked.size(), 1u);
  EXPECT_NE(r.unlinked[0].second.find("no frame"), std::string::npos);
}

}  // namespace
}  // namespace rolamos
