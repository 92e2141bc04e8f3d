// Engine patches composed into the global mosaic: placement through the links, pixels where the
// ground truth says, the paper's scaled mosaic, and patches that cannot be placed left out.
#include "rolamos/compose.hpp"
#include "rolamos/georeference.hpp"

#include <filesystem>
#include <fstream>
#include <map>

#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/survey.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

// Every level of two pyramids holds the same pixels.
void ExpectSamePixels(const std::string& a_path, const std::string& b_path) {
  auto cache = std::make_shared<TileCache>();
  TiledImage a = TiledImage::Open(a_path, cache), b = TiledImage::Open(b_path, cache);
  ASSERT_EQ(a.num_levels(), b.num_levels());
  for (int k = 0; k < a.num_levels(); ++k) {
    const auto& L = a.info().levels[size_t(k)];
    const cv::Rect all(0, 0, static_cast<int>(L.width), static_cast<int>(L.height));
    cv::Mat d;
    cv::absdiff(a.ReadRegion(k, all), b.ReadRegion(k, all), d);
    EXPECT_EQ(cv::countNonZero(d.reshape(1)), 0) << "level " << k;
  }
}

class ComposeTest : public testing::Test {
 protected:
  void SetUp() override {
    SurveyOptions so;
    so.frame_width = 480;
    so.frame_height = 360;
    so.focal_px = 420;
    so.frames = 30;
    survey_ = WriteSurvey(so, dir_ / "survey");
    store_ = std::make_unique<Store>(Store::Create(dir_ / "s.rolamos"));
    MosaickerOptions mo;
    mo.patch_megapixels = 0.4;  // several patches, linked one to the next
    mo.tiff.compression = Compression::kZstd;
    MosaicSummary sum = MosaicInput(dir_ / "survey/frames", *store_, mo);
    ASSERT_GE(sum.patches, 3);
  }
  test::ScratchDir dir_;
  Survey survey_;
  std::unique_ptr<Store> store_;
};

TEST_F(ComposeTest, PatchesLandWhereTheGroundTruthSays) {
  ComposeOptions o;
  o.tiff.compression = Compression::kZstd;
  ComposeResult r = ComposeMosaic(*store_, o);
  EXPECT_TRUE(r.left_out.empty());
  EXPECT_DOUBLE_EQ(r.scale, 1.0);
  Store s = Store::Open(dir_ / "s.rolamos");
  ASSERT_TRUE(s.HasMosaic());
  EXPECT_EQ(s.global().size[0], r.width);
  TiledImage mosaic = TiledImage::Open(s.MosaicPath(), std::make_shared<TileCache>());
  EXPECT_EQ(mosaic.width(), r.width);
  // Every frame's grid through patch_to_global against ground truth, one best-fit homography.
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : survey_.frames) gt[fs::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  std::vector<cv::Point2d> grid, ours, theirs;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j) grid.emplace_back(i * 119.75, j * 89.75);
  std::pair<cv::Matx33d, std::string> sample;
  int sample_index = 0;
  for (const auto& p : s.patches()) {
    PatchSidecar side = s.ReadSidecar(p.id);
    ASSERT_TRUE(side.patch_to_global.has_value());
    for (const auto& f : side.frames) {
      const cv::Matx33d to_mosaic = ToMatx(*side.patch_to_global) * ToMatx(f.frame_to_patch);
      std::vector<cv::Point2d> a, b;
      cv::perspectiveTransform(grid, a, cv::Mat(to_mosaic));
      cv::perspectiveTransform(grid, b, cv::Mat(gt[fs::path(f.source).filename().string()]));
      ours.insert(ours.end(), a.begin(), a.end());
      theirs.insert(theirs.end(), b.begin(), b.end());
      // A keyframe (blended, not only placed) near the middle of the survey.
      if (f.is_blended() && f.index <= 17 && f.index >= sample_index) {
        sample = {to_mosaic, fs::path(f.source).filename().string()};
        sample_index = f.index;
      }
    }
  }
  cv::Mat fit = cv::findHomography(ours, theirs, 0);
  std::vector<cv::Point2d> mapped;
  cv::perspectiveTransform(ours, mapped, fit);
  double sse = 0;
  for (size_t i = 0; i < mapped.size(); ++i) sse += std::pow(cv::norm(mapped[i] - theirs[i]), 2);
  EXPECT_LT(std::sqrt(sse / mapped.size()), 2.0);
  ASSERT_FALSE(sample.second.empty());
  // And the mosaic's pixels there show the frame.
  cv::Mat whole = mosaic.ReadRegion(0, cv::Rect(0, 0, static_cast<int>(r.width), static_cast<int>(r.height)));
  cv::Mat seen;
  cv::warpPerspective(whole, seen, cv::Mat(sample.first), cv::Size(480, 360), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
  cv::cvtColor(seen, seen, cv::COLOR_BGRA2BGR);
  cv::Mat frame = cv::imread(dir_ / ("survey/frames/" + sample.second));
  const cv::Rect centre(140, 105, 200, 150);
  EXPECT_GT(test::PsnrAfterColourFit(seen(centre), frame(centre)), 30.0);
}

TEST_F(ComposeTest, ScaledMosaicFitsThePixelLimit) {
  ComposeOptions o;
  o.max_pixels = 200000;
  ComposeResult r = ComposeMosaic(*store_, o);
  EXPECT_LT(r.scale, 1.0);
  EXPECT_LE(r.width * r.height, 200000);
  EXPECT_GT(r.width * r.height, 180000);
  EXPECT_DOUBLE_EQ(Store::Open(dir_ / "s.rolamos").global().scale, r.scale);
}

TEST_F(ComposeTest, APatchThatCannotBePlacedIsReportedNotGuessed) {
  PatchSidecar second = store_->ReadSidecar(2);
  second.link.reset();  // as if tracking had been lost before patch 2
  store_->UpdateSidecar(second);
  ComposeResult r = ComposeMosaic(*store_, ComposeOptions{});
  ASSERT_FALSE(r.left_out.empty());
  EXPECT_EQ(r.left_out.front().first, 2);
  EXPECT_NE(r.left_out.front().second.find("not linked"), std::string::npos);
  EXPECT_GE(r.patches_used, 1);
}

// A link no downward camera gives (a homography fitted to a rugose reef without calibration drew
// a patch's first frame twice its size): the patch is left out with the link's figures, and the
// patches placed through it with it, until the map is aligned; a link that scales by 1.3 stands.
TEST_F(ComposeTest, APatchWhoseLinkNoDownwardCameraGivesIsLeftOutNotDrawn) {
  PatchSidecar second = store_->ReadSidecar(2);
  ASSERT_TRUE(second.link.has_value());
  const cv::Matx33d link = ToMatx(second.link->to_previous);
  second.link->to_previous = ToArray9(link * cv::Matx33d(1.3, 0, 0, 0, 1.3, 0, 0, 0, 1));
  store_->UpdateSidecar(second);
  ComposeResult r = ComposeMosaic(*store_, ComposeOptions{});
  EXPECT_TRUE(r.left_out.empty()) << r.left_out.front().second;
  // compose stored every patch's placement; a fresh store's patches are placed by their links.
  for (const auto& e : store_->patches()) {
    PatchSidecar s = store_->ReadSidecar(e.id);
    s.patch_to_global.reset();
    if (e.id == 2) s.link->to_previous = ToArray9(link * cv::Matx33d(2.5, 0, 0, 0, 2.5, 0, 0, 0, 1));
    store_->UpdateSidecar(s);
  }
  r = ComposeMosaic(*store_, ComposeOptions{});
  ASSERT_FALSE(r.left_out.empty());
  EXPECT_EQ(r.left_out.front().first, 2);
  EXPECT_NE(r.left_out.front().second.find("link to patch 1 draws its first frame 2."), std::string::npos)
      << r.left_out.front().second;
  EXPECT_EQ(r.patches_used, 1);
}

// Killed half way (here: cancelled from the progress callback), the store still opens with its
// previous mosaic; the re-run finishes only the chunks that were missing, and the mosaic is the
// same as one composed in a single run.
TEST_F(ComposeTest, AnInterruptedComposeResumesWhereItStopped) {
  ComposeOptions o;
  o.tiff.compression = Compression::kZstd;
  o.chunk_px = 256;
  const ComposeResult whole = ComposeMosaic(*store_, o);
  ASSERT_GT(whole.chunks, 6);
  const fs::path mosaic = dir_ / "s.rolamos/mosaic.tif";
  fs::copy_file(mosaic, dir_ / "whole.tif");
  const auto before = fs::last_write_time(mosaic);
  int reports = 0;
  EXPECT_THROW(ComposeMosaic(*store_, o, [&](double) {
                 if (++reports == 5) throw Error("interrupted");
               }),
               Error);
  EXPECT_EQ(fs::last_write_time(mosaic), before);  // the old mosaic is untouched
  EXPECT_TRUE(fs::exists(dir_ / "s.rolamos/mosaic.tif.partial/journal.txt"));
  EXPECT_NO_THROW(Store::Open(dir_ / "s.rolamos"));
  const ComposeResult resumed = ComposeMosaic(*store_, o);
  EXPECT_GT(resumed.chunks_resumed, 0);
  EXPECT_LT(resumed.chunks_resumed, resumed.chunks);
  EXPECT_FALSE(fs::exists(dir_ / "s.rolamos/mosaic.tif.partial"));
  ExpectSamePixels(dir_ / "whole.tif", mosaic);
  // Other options are other pixels: a partial compose for them is not resumed.
  reports = 0;
  EXPECT_THROW(ComposeMosaic(*store_, o, [&](double) {
                 if (++reports == 3) throw Error("interrupted");
               }),
               Error);
  o.feather_px = 32;
  const ComposeResult other = ComposeMosaic(*store_, o);
  EXPECT_EQ(other.chunks_resumed, 0);
  EXPECT_NE(other.discarded.find("other patches or options"), std::string::npos);
}

// Without navigation: metres in a local frame from altitude / focal, origin at the first frame.
// A compose split into shards (as cluster jobs run it) gives the one-process mosaic pixel for
// pixel; a finish before every shard is done, a second finish while one runs, and a shard run
// after the store changed are refused with the reason.
TEST_F(ComposeTest, ShardsThenFinishEqualOneProcess) {
  ComposeOptions o;
  o.tiff.compression = Compression::kZstd;
  o.chunk_px = 256;
  o.threads = 1;
  ComposeMosaic(*store_, o);
  const fs::path mosaic = dir_ / "s.rolamos/mosaic.tif";
  fs::rename(mosaic, dir_ / "whole.tif");

  ComposeOptions shard = o;
  shard.shards = 3;
  shard.shard = 1;
  const ComposeResult first = ComposeMosaic(*store_, shard);
  EXPECT_FALSE(first.written);
  EXPECT_GT(first.chunks_rendered, 0);
  EXPECT_EQ(first.chunks_rendered, first.shard_chunks);
  EXPECT_FALSE(fs::exists(mosaic));
  ComposeOptions finish = o;
  finish.finish = true;
  try {
    ComposeMosaic(*store_, finish);
    ADD_FAILURE() << "finished with shards 2 and 3 missing";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("2/3"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("3/3"), std::string::npos) << e.what();
  }
  ShardStatus st = ComposeShardStatus(*store_);
  EXPECT_TRUE(st.split);
  EXPECT_EQ(st.pending, (std::vector<int>{2, 3}));
  // Another split of the same partial mosaic is refused.
  ComposeOptions four = shard;
  four.shards = 4;
  EXPECT_THROW(ComposeMosaic(*store_, four), Error);
  for (int k : {2, 3}) {
    shard.shard = k;
    ComposeMosaic(*store_, shard);
  }
  EXPECT_TRUE(ComposeShardStatus(*store_).pending.empty());
  // A finish that is running (its lock held by a live process on this host) keeps a second out.
  const fs::path lock = dir_ / "s.rolamos/mosaic.tif.partial/finish.lock";
  char host[256] = {};
  gethostname(host, sizeof host - 1);
  { std::ofstream(lock) << host << " " << getpid() << " 0\n"; }
  try {
    ComposeMosaic(*store_, finish);
    ADD_FAILURE() << "a second finish ran";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("another finish"), std::string::npos) << e.what();
  }
  // One whose process is gone is taken over.
  { std::ofstream(lock) << host << " 999999999 0\n"; }
  const ComposeResult done = ComposeMosaic(*store_, finish);
  EXPECT_TRUE(done.written);
  EXPECT_FALSE(fs::exists(dir_ / "s.rolamos/mosaic.tif.partial"));
  ExpectSamePixels(dir_ / "whole.tif", mosaic);

  // The store changes between two shards of a new split: the later shard refuses.
  shard.shard = 1;
  ComposeMosaic(*store_, shard);
  PatchSidecar s = store_->ReadSidecar(store_->patches().back().id);
  (*s.patch_to_global)[2] += 5;  // the patch moved (a new alignment)
  store_->UpdateSidecar(s);
  shard.shard = 2;
  try {
    ComposeMosaic(*store_, shard);
    ADD_FAILURE() << "a shard ran against a changed store";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("changed since the split"), std::string::npos) << e.what();
  }
}

// Multi-band blending, rendered block by block: the same coverage as feathering, close to it in
// colour, and blocks of other sizes agree where they meet (each block's pyramid sees a margin).
TEST_F(ComposeTest, MultibandCoversTheSameGroundAndBlocksAgree) {
  ComposeOptions o;
  o.tiff.compression = Compression::kZstd;
  o.chunk_px = 256;
  o.exposure = false;
  auto read = [&](const ComposeOptions& opts) {
    ComposeMosaic(*store_, opts);
    auto cache = std::make_shared<TileCache>();
    TiledImage m = TiledImage::Open(dir_ / "s.rolamos/mosaic.tif", cache);
    return m.ReadRegion(0, cv::Rect(0, 0, static_cast<int>(m.width()), static_cast<int>(m.height()))).clone();
  };
  const cv::Mat feather = read(o);
  o.bands = 5;
  const cv::Mat small_blocks = read(o);
  o.chunk_px = 1024;
  const cv::Mat large_blocks = read(o);
  ASSERT_EQ(feather.size(), small_blocks.size());
  std::vector<cv::Mat> f, a, b;
  cv::split(feather, f);
  cv::split(small_blocks, a);
  cv::split(large_blocks, b);
  // (The same coverage but for single pixels at the outer border, where the two round differently.)
  EXPECT_LE(cv::countNonZero(f[3] != a[3]), static_cast<int>(f[3].total() / 1000)) << "coverage differs from feathering";
  const cv::Mat inside = f[3] > 0;
  for (int c = 0; c < 3; ++c) {
    cv::Mat d;
    cv::absdiff(a[c], f[c], d);
    EXPECT_LT(cv::mean(d, inside)[0], 4.0) << "channel " << c << ": far from the feathered colours";
    cv::absdiff(a[c], b[c], d);
    EXPECT_LT(cv::mean(d, inside)[0], 0.5) << "channel " << c << ": blocks of 256 and 1024 disagree";
    EXPECT_LE(cv::countNonZero(d > 4), d.total() / 1000) << "channel " << c;
  }
}

TEST_F(ComposeTest, ALocalEngineeringFrameWithoutNavigation) {
  EXPECT_THROW(GeoreferenceLocal(*store_, 0.002), Error);  // no mosaic yet
  ComposeMosaic(*store_, ComposeOptions{});
  EXPECT_THROW(GeoreferenceLocal(*store_, 0), Error);
  EXPECT_THROW(GeoreferenceLocal(*store_, std::nan("")), Error);
  const Georef g = GeoreferenceLocal(*store_, 2.0 / 420);  // 2 m altitude, 420 px focal
  const auto read = ReadGeoref(Store::Open(dir_ / "s.rolamos").MosaicPath());
  ASSERT_TRUE(read.has_value());
  EXPECT_NE(read->crs.find("rolamos local engineering frame"), std::string::npos) << read->crs;
  EXPECT_NEAR(read->geotransform[1], 2.0 / 420, 1e-9);
  EXPECT_NEAR(read->geotransform[5], -2.0 / 420, 1e-9);
  // The first frame's centre is the origin.
  const PatchSidecar first = store_->ReadSidecar(store_->patches().front().id);
  const cv::Vec3d c = ToMatx(*first.patch_to_global) * ToMatx(first.frames.front().frame_to_patch) * cv::Vec3d(239.5, 179.5, 1);
  const auto xy = read->PixelToMap(c[0] / c[2], c[1] / c[2]);
  EXPECT_NEAR(xy[0], 0, 1e-6);
  EXPECT_NEAR(xy[1], 0, 1e-6);
  EXPECT_TRUE(Store::Open(dir_ / "s.rolamos").global().georef.has_value());
}

// A damaged patch costs that patch (and any placed only through its link), with the reason; the
// rest is composed.
TEST_F(ComposeTest, BrokenPatchesAreLeftOutWithTheReason) {
  const auto ids = store_->patches();
  ASSERT_GE(ids.size(), 3u);
  ComposeMosaic(*store_, ComposeOptions{});  // every patch gets its own placement
  // The last patch's image cut short, the one before it placed at infinity.
  const std::string last = store_->PatchImagePath(ids.back().id);
  fs::resize_file(last, fs::file_size(last) / 3);
  PatchSidecar s = store_->ReadSidecar(ids[ids.size() - 2].id);
  s.patch_to_global = Homography{1, 0, 0, 0, 1, 0, -0.01, 0, 1};
  store_->UpdateSidecar(s);
  ComposeResult r = ComposeMosaic(*store_, ComposeOptions{});
  ASSERT_EQ(r.left_out.size(), 2u);
  EXPECT_EQ(r.left_out[0].first, ids[ids.size() - 2].id);
  EXPECT_NE(r.left_out[0].second.find("infinity"), std::string::npos) << r.left_out[0].second;
  EXPECT_EQ(r.left_out[1].first, ids.back().id);
  EXPECT_NE(r.left_out[1].second.find(fs::path(last).filename().string()), std::string::npos) << r.left_out[1].second;
  EXPECT_EQ(r.patches_used, static_cast<int>(ids.size()) - 2);
  EXPECT_TRUE(Store::Open(dir_ / "s.rolamos").HasMosaic());
  // A sidecar that disagrees with its image.
  PatchSidecar first = store_->ReadSidecar(ids.front().id);
  first.size[0] += 10;
  store_->UpdateSidecar(first);
  r = ComposeMosaic(*store_, ComposeOptions{});
  ASSERT_FALSE(r.left_out.empty());
  EXPECT_EQ(r.left_out[0].first, ids.front().id);
  EXPECT_NE(r.left_out[0].second.find("sidecar says"), std::string::npos) << r.left_out[0].second;
}

TEST_F(ComposeTest, ImpossibleOptionsAreRefusedBeforeWork) {
  ComposeOptions o;
  o.chunk_px = 1000;
  EXPECT_THROW(ComposeMosaic(*store_, o), Error);
  o.chunk_px = 4096;
  o.threads = -1;
  EXPECT_THROW(ComposeMosaic(*store_, o), Error);
  EXPECT_FALSE(fs::exists(dir_ / "s.rolamos/mosaic.tif"));
}

}  // namespace
}  // namespace rolamos

namespace rolamos {
namespace {

// Navigation made from the ground truth (2 mm a texture pixel, in UTM 55S): the fitted
// georeference must put every frame centre where its navigation does.
TEST_F(ComposeTest, NavigationGeoreferencesTheMosaic) {
  ComposeResult r = ComposeMosaic(*store_, ComposeOptions{});
  ASSERT_TRUE(r.left_out.empty());
  const std::string csv = dir_ / "nav.csv";
  {
    std::ofstream out(csv);
    out << "frame,epsg,gt0_E0,gt1_dE_dcol,gt2_dE_drow,gt3_N0,gt4_dN_dcol,gt5_dN_drow\n";
    for (const auto& f : survey_.frames) {
      // Navigation is one affine per frame: frame -> world linearised at the frame centre, then
      // 2 mm per texture pixel east and south of an origin.
      const cv::Matx33d W = ToMatx(f.frame_to_world);
      const cv::Vec3d c = W * cv::Vec3d(239.5, 179.5, 1), cx = W * cv::Vec3d(240.5, 179.5, 1),
                      cy = W * cv::Vec3d(239.5, 180.5, 1);
      const double wx = c[0] / c[2], wy = c[1] / c[2];
      const double dxc = cx[0] / cx[2] - wx, dyc = cx[1] / cx[2] - wy;
      const double dxr = cy[0] / cy[2] - wx, dyr = cy[1] / cy[2] - wy;
      const double E0 = 500000 + 0.002 * (wx - 239.5 * dxc - 179.5 * dxr);
      const double N0 = 5200000 - 0.002 * (wy - 239.5 * dyc - 179.5 * dyr);
      out.precision(12);
      out << fs::path(f.file).filename().string() << ",32755," << E0 << "," << 0.002 * dxc << ","
          << 0.002 * dxr << "," << N0 << "," << -0.002 * dyc << "," << -0.002 * dyr << "\n";
    }
  }
  GeoreferenceResult g = GeoreferenceMosaic(*store_, ReadFrameNavigationCsv(csv));
  EXPECT_EQ(g.frames_used, 30);
  EXPECT_LT(g.median_residual_m, 0.01);  // 5 texture pixels
  EXPECT_NEAR(std::hypot(g.georef.geotransform[1], g.georef.geotransform[4]), 0.002, 0.0002);
  auto back = ReadGeoref(dir_ / "s.rolamos/mosaic.tif");
  ASSERT_TRUE(back.has_value());
  EXPECT_NE(back->crs.find("UTM zone 55S"), std::string::npos);
  EXPECT_TRUE(Store::Open(dir_ / "s.rolamos").global().georef.has_value());
}

TEST(Navigation, MalformedCsvIsNamed) {
  test::ScratchDir dir;
  std::ofstream(dir / "a.csv") << "frame,epsg,gt0\n1.tif,32755,5\n";
  EXPECT_NE(test::ErrorOf([&] { ReadFrameNavigationCsv(dir / "a.csv"); }).find("gt0..gt5"), std::string::npos);
  std::ofstream(dir / "b.csv") << "frame,epsg,gt0,gt1,gt2,gt3,gt4,gt5\n1.tif,32755,5,x,0,1,0,-1\n";
  EXPECT_NE(test::ErrorOf([&] { ReadFrameNavigationCsv(dir / "b.csv"); }).find("b.csv:2: column gt1 is not a number"),
            std::string::npos);
}

}  // namespace
}  // namespace rolamos
