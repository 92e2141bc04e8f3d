#include "rolamos/tiff_writer.hpp"

#include <algorithm>
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"
#include "raster/tiff_inspect.h"

namespace rolamos {
namespace {

using test::MakeImage;
using test::ScratchDir;

struct Case {
  Compression compression;
  int channels;
  int bits;
  int tile;
};

std::string Name(const testing::TestParamInfo<Case>& info) {
  std::string codec = CompressionName(info.param.compression);
  std::replace(codec.begin(), codec.end(), '-', '_');
  return codec + "_c" + std::to_string(info.param.channels) +
         "_b" + std::to_string(info.param.bits) + "_t" + std::to_string(info.param.tile);
}

class RoundTrip : public testing::TestWithParam<Case> {};

// Odd, non-tile-multiple sizes exercise partial edge tiles and odd pyramid halvings.
TEST_P(RoundTrip, EveryLevelReadsBackAsWritten) {
  const Case c = GetParam();
  ScratchDir dir;
  cv::Mat image = MakeImage(1333, 777, c.channels, c.bits);
  TiffWriteOptions o;
  o.compression = c.compression;
  o.tile_size = c.tile;
  const std::string path = dir / "out.tif";
  TiffWriteStats stats = WritePyramidTiff(path, image, o);

  auto cache = std::make_shared<TileCache>();
  TiledImage t = TiledImage::Open(path, cache);
  EXPECT_TRUE(t.info().bigtiff);
  EXPECT_EQ(t.info().channels, c.channels);
  EXPECT_EQ(t.info().bits, c.bits);
  EXPECT_EQ(t.info().has_alpha, c.channels == 2 || c.channels == 4);
  EXPECT_EQ(t.info().compression, CompressionName(c.compression));
  // Levels halve (rounding up) until one tile holds the level.
  ASSERT_EQ(t.num_levels(), stats.levels);
  long long w = 1333, h = 777;
  for (int k = 0; k < t.num_levels(); ++k) {
    EXPECT_EQ(t.info().levels[k].width, w) << "level " << k;
    EXPECT_EQ(t.info().levels[k].height, h) << "level " << k;
    EXPECT_EQ(t.info().levels[k].tile_width, c.tile);
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
  EXPECT_LE(std::max(t.info().levels.back().width, t.info().levels.back().height), c.tile);
  EXPECT_GT(std::max(t.info().levels[t.num_levels() - 2].width,
                     t.info().levels[t.num_levels() - 2].height),
            c.tile);

  cv::Mat back = t.ReadRegion(0, cv::Rect(0, 0, 1333, 777));
  ASSERT_EQ(back.type(), image.type());
  if (IsLossless(c.compression)) {
    EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0);
  } else if (c.channels == 3 || c.channels == 1) {
    // The procedural texture has 2-pixel noise, harsher than seafloor photos: the 40 dB figure
    // is checked on a real photo in RealPhotoJpegQ90IsAbove40dB.
    EXPECT_GE(test::Psnr(back, image), 38.0);
  } else {
    // Colours under alpha = 0 are free for the codec (WebP drops them): compare where data is.
    EXPECT_GE(test::MaskedPsnr(back, image), 33.0);  // 4-sample JPEG has no chroma model
  }
  // A region inside, not aligned to tiles.
  cv::Rect r(301, 123, 517, 389);
  cv::Mat part = t.ReadRegion(0, r);
  EXPECT_EQ(cv::norm(part, back(r), cv::NORM_INF), 0.0);
}

INSTANTIATE_TEST_SUITE_P(
    Codecs, RoundTrip,
    testing::Values(Case{Compression::kNone, 3, 8, 256}, Case{Compression::kDeflate, 3, 8, 256},
                    Case{Compression::kZstd, 4, 8, 256}, Case{Compression::kZstd, 1, 8, 512},
                    Case{Compression::kZstd, 2, 8, 256}, Case{Compression::kDeflate, 4, 16, 256},
                    Case{Compression::kZstd, 3, 16, 512}, Case{Compression::kNone, 1, 16, 256},
                    Case{Compression::kJpeg, 3, 8, 256}, Case{Compression::kJpeg, 1, 8, 256},
                    Case{Compression::kJpeg, 3, 8, 512}, Case{Compression::kJpeg, 4, 8, 256},
                    Case{Compression::kWebp, 3, 8, 256}, Case{Compression::kWebp, 4, 8, 256},
                    Case{Compression::kJpegMask, 4, 8, 256}, Case{Compression::kJpegMask, 2, 8, 512}),
    Name);

// WebP tiles come from libwebp directly (libtiff cannot set its effort): at the engine's fast
// effort they must still read back through libtiff/OpenImageIO and GDAL alike, alpha exactly.
TEST(PyramidTiffWriter, FastWebpTilesReadBackEverywhereWithExactAlpha) {
  ScratchDir dir;
  cv::Mat image = MakeImage(700, 500, 4, 8);
  cv::Mat alpha(image.size(), CV_8U, cv::Scalar(255));
  cv::circle(alpha, {350, 250}, 200, cv::Scalar(0), cv::FILLED);
  cv::insertChannel(alpha, image, 3);
  for (int method : {0, 4}) {
    TiffWriteOptions o;
    o.compression = Compression::kWebp;
    o.webp_method = method;
    const std::string path = dir / ("m" + std::to_string(method) + ".tif");
    WritePyramidTiff(path, image, o);
    auto cache = std::make_shared<TileCache>();
    cv::Mat back = TiledImage::Open(path, cache).ReadRegion(0, cv::Rect(0, 0, 700, 500));
    cv::Mat back_alpha;
    cv::extractChannel(back, back_alpha, 3);
    EXPECT_EQ(cv::norm(back_alpha, alpha, cv::NORM_INF), 0.0) << "method " << method;
    EXPECT_GE(test::MaskedPsnr(back, image), 33.0) << "method " << method;
    const auto gdal = test::RunShell("gdalinfo -checksum " + path);
    EXPECT_EQ(gdal.exit_code, 0) << gdal.output;
    EXPECT_EQ(gdal.output.find("ERROR"), std::string::npos) << gdal.output;
  }
  TiffWriteOptions bad;
  bad.webp_method = 7;
  std::string error;
  PixelLayout rgba;
  rgba.width = rgba.height = 64;
  rgba.channels = 4;
  EXPECT_FALSE(bad.IsValid(rgba, &error));
  EXPECT_NE(error.find("webp method"), std::string::npos);
}

// jpeg-mask: the colour as JPEG, the alpha as GDAL's per-level masks. rolamos reads the mask back
// as alpha (0 or 255: alpha >= 128 is data) at every level, GDAL as the dataset's mask band, and
// OpenImageIO the colour.
TEST(PyramidTiffWriter, JpegMaskKeepsTheAlphaAsMasksEveryReaderSees) {
  ScratchDir dir;
  cv::Mat image = MakeImage(700, 500, 4, 8);
  cv::Mat alpha(image.size(), CV_8U, cv::Scalar(255));
  cv::circle(alpha, {350, 250}, 200, cv::Scalar(0), cv::FILLED);
  cv::rectangle(alpha, cv::Rect(0, 0, 61, 700), cv::Scalar(0), cv::FILLED);
  cv::insertChannel(alpha, image, 3);
  TiffWriteOptions o;
  o.compression = Compression::kJpegMask;
  o.quality = 85;
  const std::string path = dir / "masked.tif";
  WritePyramidTiff(path, image, o);
  // The levels' alpha as the lossless pyramid holds it, thresholded as the mask keeps it.
  TiffWriteOptions lossless;
  lossless.compression = Compression::kZstd;
  WritePyramidTiff(dir / "lossless.tif", image, lossless);

  auto cache = std::make_shared<TileCache>();
  TiledImage t = TiledImage::Open(path, cache), ref = TiledImage::Open(dir / "lossless.tif", cache);
  EXPECT_EQ(t.info().channels, 4);
  EXPECT_TRUE(t.info().has_alpha);
  EXPECT_EQ(t.info().compression, "jpeg-mask");
  ASSERT_EQ(t.num_levels(), ref.num_levels());
  ASSERT_EQ(t.num_levels(), 3);
  for (int level = 0; level < t.num_levels(); ++level) {
    const auto& l = t.info().levels[size_t(level)];
    const cv::Rect all(0, 0, int(l.width), int(l.height));
    cv::Mat back = t.ReadRegion(level, all), truth = ref.ReadRegion(level, all), a, b;
    cv::extractChannel(back, a, 3);
    cv::extractChannel(truth, b, 3);
    cv::Mat expected = b >= 128;
    EXPECT_EQ(cv::norm(a, expected, cv::NORM_INF), 0.0) << "level " << level;
    if (level == 0) EXPECT_GE(test::MaskedPsnr(back, image), 38.0);
  }
  const auto info = test::RunShell("gdalinfo " + path);
  EXPECT_NE(info.output.find("Mask Flags: PER_DATASET"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("Overviews of mask band: 350x250, 175x125"), std::string::npos) << info.output;
  const auto png = test::RunShell("gdal_translate -q -of PNG -b mask " + path + " " + (dir / "mask.png"));
  ASSERT_EQ(png.exit_code, 0) << png.output;
  EXPECT_EQ(cv::norm(cv::imread(dir / "mask.png", cv::IMREAD_UNCHANGED), alpha, cv::NORM_INF), 0.0);
  const auto oiio = test::RunShell("iinfo " + path);
  EXPECT_NE(oiio.output.find("700 x  500, 3 channel, uint8 tiff"), std::string::npos) << oiio.output;
  // Without alpha there is nothing to mask: a plain JPEG pyramid.
  WritePyramidTiff(dir / "rgb.tif", MakeImage(300, 300, 3, 8), o);
  EXPECT_EQ(TiledImage::Open(dir / "rgb.tif", cache).info().compression, "jpeg");
  EXPECT_EQ(InspectTiff(dir / "rgb.tif").directories.size(), 2u);
}

TEST(PyramidTiffWriter, ReducedLevelsAreAreaAveragesAndNeverDarkenAtDataBorders) {
  ScratchDir dir;
  cv::Mat image = MakeImage(1024, 1024, 4, 8);
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(dir / "a.tif", image, o);
  TiledImage t = TiledImage::Open(dir / "a.tif", std::make_shared<TileCache>());
  cv::Mat level1 = t.ReadRegion(1, cv::Rect(0, 0, 512, 512));
  // Expected: alpha-weighted 2x2 means.
  int checked = 0;
  for (int y = 0; y < 512; y += 7) {
    for (int x = 0; x < 512; x += 5) {
      double sum_a = 0, sum_c[3] = {0, 0, 0};
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
          cv::Vec4b p = image.at<cv::Vec4b>(2 * y + dy, 2 * x + dx);
          sum_a += p[3];
          for (int c = 0; c < 3; ++c) sum_c[c] += double(p[c]) * p[3];
        }
      cv::Vec4b got = level1.at<cv::Vec4b>(y, x);
      EXPECT_NEAR(got[3], sum_a / 4, 1.0);
      if (sum_a > 0) {
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], sum_c[c] / sum_a, 1.0);
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
  // At the border of the data the coarsest level keeps the colour: compare mean colour of
  // partly covered pixels against fully covered ones (a plain average would be much darker).
  cv::Mat top = t.ReadRegion(t.num_levels() - 1, cv::Rect(0, 0, 256, 256));
  cv::Mat alpha;
  cv::extractChannel(top, alpha, 3);
  cv::Mat border = (alpha > 20) & (alpha < 200), inner = alpha == 255;
  ASSERT_GT(cv::countNonZero(border), 20);
  cv::Scalar mb = cv::mean(top, border), mi = cv::mean(top, inner);
  for (int c = 0; c < 3; ++c) EXPECT_GT(mb[c], 0.85 * mi[c]) << "channel " << c;
}

TEST(PyramidTiffWriter, RealPhotoJpegQ90IsAbove40dB) {
  const std::string data = test::SharedData();
  if (data.empty()) GTEST_SKIP() << "../shared/data is absent";
  cv::Mat photo = cv::imread(data + "/seattle_rov_gopro_large/2024_10_08_10-37-22.JPG");
  ASSERT_FALSE(photo.empty());
  cv::Mat crop = photo(cv::Rect(1000, 1000, 2048, 1536)).clone();
  ScratchDir dir;
  TiffWriteOptions o;  // JPEG q90 is the default
  WritePyramidTiff(dir / "photo.tif", crop, o);
  TiledImage t = TiledImage::Open(dir / "photo.tif", std::make_shared<TileCache>());
  const double psnr = test::Psnr(t.ReadRegion(0, cv::Rect(0, 0, 2048, 1536)), crop);
  RecordProperty("psnr_db", std::to_string(psnr));
  EXPECT_GE(psnr, 40.0);
}

TEST(PyramidTiffWriter, SingleTileImageHasOneLevelAndWithoutPyramidOnlyOne) {
  ScratchDir dir;
  TiffWriteOptions o;
  o.compression = Compression::kDeflate;
  EXPECT_EQ(WritePyramidTiff(dir / "small.tif", MakeImage(200, 100), o).levels, 1);
  o.pyramid = false;
  EXPECT_EQ(WritePyramidTiff(dir / "flat.tif", MakeImage(2000, 1000), o).levels, 1);
}

TEST(PyramidTiffWriter, AbandonedWriterLeavesNothingBehind) {
  ScratchDir dir;
  const std::string path = dir / "partial.tif";
  {
    PixelLayout layout;
    layout.width = 1000;
    layout.height = 1000;
    PyramidTiffWriter w(path, layout, TiffWriteOptions{});
    w.WriteBand(MakeImage(1000, 256));
    EXPECT_THROW(w.Finish(), Error);  // incomplete
  }
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

TEST(PyramidTiffWriter, RejectsImpossibleOptionsWithReasons) {
  ScratchDir dir;
  PixelLayout layout;
  layout.width = 100;
  layout.height = 100;
  auto expect_error = [&](PixelLayout l, TiffWriteOptions o, const std::string& words) {
    try {
      PyramidTiffWriter w(dir / "x.tif", l, o);
      ADD_FAILURE() << "accepted: " << words;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("x.tif"), std::string::npos) << e.what();
    }
  };
  TiffWriteOptions o;
  o.tile_size = 300;
  expect_error(layout, o, "tile size 300");
  o = {};
  o.quality = 0;
  expect_error(layout, o, "quality 0");
  PixelLayout l16 = layout;
  l16.bits = 16;
  expect_error(l16, TiffWriteOptions{}, "8-bit samples only");
  PixelLayout zero = layout;
  zero.width = 0;
  expect_error(zero, TiffWriteOptions{}, "empty");
  PixelLayout absurd = layout;
  absurd.width = 1LL << 40;
  expect_error(absurd, TiffWriteOptions{}, "larger than a TIFF can hold");
  PixelLayout gray = layout;
  gray.channels = 1;
  o = {};
  o.compression = Compression::kWebp;
  expect_error(gray, o, "webp needs colour");
}

TEST(PyramidTiffWriter, RejectsBandsOfTheWrongShape) {
  ScratchDir dir;
  PixelLayout layout;
  layout.width = 600;
  layout.height = 600;
  PyramidTiffWriter w(dir / "x.tif", layout, TiffWriteOptions{});
  EXPECT_THROW(w.WriteBand(MakeImage(500, 256)), Error);
  EXPECT_THROW(w.WriteBand(MakeImage(600, 100)), Error);
  EXPECT_THROW(w.WriteBand(MakeImage(600, 256, 4)), Error);
}

TEST(PyramidTiffWriter, StreamedAndInMemoryWritesAgree) {
  // Band-by-band with odd band boundaries of the caller vs. one in-memory call: same pixels.
  ScratchDir dir;
  cv::Mat image = MakeImage(900, 700, 3);
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(dir / "a.tif", image, o);
  PixelLayout layout;
  layout.width = 900;
  layout.height = 700;
  PyramidTiffWriter w(dir / "b.tif", layout, o);
  for (int y = 0; y < 700; y += 256) w.WriteBand(image.rowRange(y, std::min(700, y + 256)).clone());
  w.Finish();
  auto cache = std::make_shared<TileCache>();
  TiledImage a = TiledImage::Open(dir / "a.tif", cache), b = TiledImage::Open(dir / "b.tif", cache);
  for (int k = 0; k < a.num_levels(); ++k) {
    cv::Rect r(0, 0, static_cast<int>(a.info().levels[k].width),
               static_cast<int>(a.info().levels[k].height));
    EXPECT_EQ(cv::norm(a.ReadRegion(k, r), b.ReadRegion(k, r), cv::NORM_INF), 0.0);
  }
}

}  // namespace
}  // namespace rolamos
