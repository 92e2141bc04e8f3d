#include "rolamos/link_patches.hpp"

#include <filesystem>
#include <algorithm>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/survey.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

// Two featureless frames lose the track: the engine starts an unlinked patch, compose leaves it
// out; place recognition finds where its first frame was seen and links it, and the composed
// mosaic then holds every frame where the ground truth says.
TEST(LinkPatches, RelinksAPatchAfterLostTrackingByItsFrames) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(24), dir / "survey");
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
  ASSERT_FALSE(store.ReadSidecar(2).link.has_value());
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  EXPECT_EQ(ComposeMosaic(store, co).left_out.size(), 1u);

  const LinkSummary r = LinkPatches(store, LinkOptions{});
  for (const auto& [id, why] : r.unlinked) ADD_FAILURE() << "patch " << id << ": " << why;
  ASSERT_EQ(r.linked.size(), 1u);
  EXPECT_EQ(r.linked[0], std::make_pair(2, 1));
  EXPECT_TRUE(r.unlinked.empty());
  const auto link = store.ReadSidecar(2).link.value();
  EXPECT_EQ(link.method, "place_recognition");
  EXPECT_GE(link.inliers.value_or(0), 40);
  const ComposeResult c = ComposeMosaic(store, co);
  EXPECT_EQ(c.patches_used, 2);
  EXPECT_TRUE(c.left_out.empty());
  // Every frame against the ground truth after one best-fit homography for the whole map.
  const std::vector<double> errors = test::ErrorsAgainstTruth(store, survey);
  const double worst = *std::max_element(errors.begin(), errors.end());
  EXPECT_LT(worst, 4.0);
}

// A patch whose frames match nothing before it stays unlinked, with the reason.
TEST(LinkPatches, ReportsWhatItCannotLink) {
  test::ScratchDir dir;
  SurveyOptions so = test::SmallSurvey(8);
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
