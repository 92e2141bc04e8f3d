#include "rolamos/cog_export.hpp"
#include "rolamos/region_export.hpp"

#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

using test::MakeImage;
using test::ScratchDir;

const Georef kUtm55{"EPSG:32755", {512000.0, 0.005, 0.0, 5250000.0, 0.0, -0.005}};

TEST(Georef, WrittenTagsAreWhatGdalSees) {
  ScratchDir dir;
  TiffWriteOptions o;
  o.compression = Compression::kDeflate;
  WritePyramidTiff(dir / "g.tif", MakeImage(1200, 800), o, &kUtm55);
  auto g = ReadGeoref(dir / "g.tif");
  ASSERT_TRUE(g.has_value());
  for (int i = 0; i < 6; ++i) EXPECT_DOUBLE_EQ(g->geotransform[i], kUtm55.geotransform[i]);
  EXPECT_NE(g->crs.find("UTM zone 55S"), std::string::npos);
  if (test::HaveCommand("gdalinfo")) {
    auto r = test::RunShell("gdalinfo " + (dir / "g.tif"));
    EXPECT_NE(r.output.find("UTM zone 55S"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("Origin = (512000.000000000000000,5250000.000000000000000)"),
              std::string::npos) << r.output;
    EXPECT_NE(r.output.find("Overviews: 600x400, 300x200"), std::string::npos) << r.output;
  }
  // Still a pyramid OpenImageIO reads after GDAL added the tags.
  EXPECT_EQ(TiledImage::Open(dir / "g.tif", std::make_shared<TileCache>()).num_levels(), 4);
}

TEST(Georef, BadCrsAndDegenerateTransformsAreRefused) {
  ScratchDir dir;
  Georef bad = kUtm55;
  bad.crs = "EPSG:999999999";
  try {
    WritePyramidTiff(dir / "g.tif", MakeImage(300, 300), TiffWriteOptions{}, &bad);
    ADD_FAILURE() << "accepted a bad CRS";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("EPSG:999999999"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "g.tif"));
  Georef flat = kUtm55;
  flat.geotransform = {0, 0, 0, 0, 0, 0};
  std::string error;
  EXPECT_FALSE(flat.IsValid(&error));
  EXPECT_NE(error.find("degenerate"), std::string::npos);
  Georef nan = kUtm55;
  nan.geotransform[1] = std::nan("");
  EXPECT_FALSE(nan.IsValid(&error));
}

TEST(Georef, WindowKeepsMapCoordinates) {
  Georef w = kUtm55.ForWindow(100, 40, 0.25);
  auto a = kUtm55.PixelToMap(100 + 4 * 10, 40 + 4 * 6);
  auto b = w.PixelToMap(10, 6);
  EXPECT_NEAR(a[0], b[0], 1e-9);
  EXPECT_NEAR(a[1], b[1], 1e-9);
}

class ExportTest : public testing::Test {
 protected:
  void SetUp() override {
    image_ = MakeImage(2100, 1500, 4);
    TiffWriteOptions o;
    o.compression = Compression::kZstd;
    WritePyramidTiff(dir_ / "src.tif", image_, o, &kUtm55);
    source_ = std::make_unique<TiledImage>(TiledImage::Open(dir_ / "src.tif", cache_));
  }
  ScratchDir dir_;
  cv::Mat image_;
  std::shared_ptr<TileCache> cache_ = std::make_shared<TileCache>();
  std::unique_ptr<TiledImage> source_;
};

TEST_F(ExportTest, FullResolutionRegionIsExact) {
  ExportOptions o;
  o.region = cv::Rect2d(300, 200, 700, 500);
  o.output = dir_ / "r.png";
  ExportResult r = ExportRegion(*source_, o);
  EXPECT_EQ(r.width, 700);
  EXPECT_EQ(r.level, 0);
  cv::Mat png = cv::imread(o.output, cv::IMREAD_UNCHANGED);
  EXPECT_EQ(cv::norm(png, image_(cv::Rect(300, 200, 700, 500)), cv::NORM_INF), 0.0);
}

TEST_F(ExportTest, StreamedTiffAndInMemoryPngAgreeAtAnyScale) {
  for (double scale : {1.0, 0.5, 0.3}) {
    ExportOptions o;
    o.region = cv::Rect2d(111, 222, 1500, 1100);
    o.scale = scale;
    o.tiff.compression = Compression::kZstd;
    o.output = dir_ / "s.tif";
    ExportResult a = ExportRegion(*source_, o);
    o.output = dir_ / "s.png";
    ExportResult b = ExportRegion(*source_, o);
    ASSERT_EQ(a.width, b.width);
    ASSERT_EQ(a.height, b.height);
    TiledImage t = TiledImage::Open(dir_ / "s.tif", cache_);
    cv::Mat tif = t.ReadRegion(0, cv::Rect(0, 0, static_cast<int>(a.width), static_cast<int>(a.height)));
    cv::Mat png = cv::imread(dir_ / "s.png", cv::IMREAD_UNCHANGED);
    EXPECT_LE(cv::norm(tif, png, cv::NORM_INF), 1.0) << "scale " << scale;
    cache_->Invalidate(dir_ / "s.tif");
    // The export carries the georeference of its window.
    auto g = ReadGeoref(dir_ / "s.tif");
    ASSERT_TRUE(g.has_value());
    auto expect = kUtm55.PixelToMap(111, 222);
    EXPECT_NEAR(g->geotransform[0], expect[0], 1e-6);
    EXPECT_NEAR(g->geotransform[1], kUtm55.geotransform[1] / scale, 1e-12);
  }
}

TEST_F(ExportTest, BadRequestsAreRefused) {
  ExportOptions o;
  o.output = dir_ / "x.png";
  o.region = cv::Rect2d(2000, 0, 200, 100);
  EXPECT_THROW(ExportRegion(*source_, o), Error);
  o.region = {};
  o.output = dir_ / "x.bmpx";
  EXPECT_THROW(ExportRegion(*source_, o), Error);
  o.output = dir_ / "x.png";
  o.scale = 3;
  EXPECT_THROW(ExportRegion(*source_, o), Error);
  o.scale = 1;
  o.max_memory_pixels = 1000;
  try {
    ExportRegion(*source_, o);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("export to .tif"), std::string::npos);
  }
  EXPECT_FALSE(std::filesystem::exists(dir_ / "x.png"));
}

TEST_F(ExportTest, CogPassesGdalsValidator) {
  if (!test::HaveCommand("python3") ||
      test::RunShell("/usr/bin/python3 -c 'import osgeo_utils.samples.validate_cloud_optimized_geotiff'")
              .exit_code != 0)
    GTEST_SKIP() << "python3-gdal not installed";
  for (Compression c : {Compression::kJpeg, Compression::kJpegMask, Compression::kZstd}) {
    CogOptions co;
    co.compression = c;
    const std::string out = dir_ / ("cog-" + CompressionName(c) + ".tif");
    ExportCog(dir_ / "src.tif", out, co);
    auto r = test::RunShell("/usr/bin/python3 -m osgeo_utils.samples.validate_cloud_optimized_geotiff " + out);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("is a valid cloud optimized GeoTIFF"), std::string::npos) << r.output;
    auto g = ReadGeoref(out);
    ASSERT_TRUE(g.has_value());
    EXPECT_DOUBLE_EQ(g->geotransform[0], kUtm55.geotransform[0]);
    // The COG reads back through our reader too (JPEG turns alpha into a mask).
    TiledImage cog = TiledImage::Open(out, cache_);
    EXPECT_GE(cog.num_levels(), 3);
    cv::Mat px = cog.ReadRegion(0, cv::Rect(900, 600, 300, 300));
    cv::Mat ref;
    cv::cvtColor(image_(cv::Rect(900, 600, 300, 300)), ref, cv::COLOR_BGRA2BGR);
    if (px.channels() == 4) cv::cvtColor(px, px, cv::COLOR_BGRA2BGR);
    EXPECT_GE(test::Psnr(px, ref), c == Compression::kZstd ? 99.0 : 30.0) << CompressionName(c);
    // The alpha survives: kept as a band (zstd) or as GDAL's 1-bit mask (JPEG), which reads back
    // as alpha 0 or 255 where the source's alpha is.
    EXPECT_TRUE(cog.info().has_alpha) << CompressionName(c);
    const cv::Mat all = cog.ReadRegion(0, cv::Rect(0, 0, image_.cols, image_.rows));
    ASSERT_EQ(all.channels(), 4) << CompressionName(c);
    cv::Mat alpha, want;
    cv::extractChannel(all, alpha, 3);
    cv::extractChannel(image_, want, 3);
    EXPECT_EQ(cv::countNonZero(alpha != want), 0) << CompressionName(c);
  }
}

}  // namespace
}  // namespace rolamos
