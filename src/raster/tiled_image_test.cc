#include "rolamos/tiled_image.hpp"

#include <tiffio.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiff_writer.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

using test::ErrorOf;

using test::MakeImage;
using test::ScratchDir;

std::string WriteSample(const ScratchDir& dir, Compression c, int w = 1500, int h = 1100) {
  TiffWriteOptions o;
  o.compression = c;
  const std::string path = dir / ("sample-" + CompressionName(c) + ".tif");
  WritePyramidTiff(path, MakeImage(w, h), o);
  return path;
}

// Offset and size of tile `index` of IFD 0.
std::pair<uint64_t, uint64_t> TileBytes(const std::string& path, uint32_t index) {
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  EXPECT_NE(tif, nullptr);
  auto r = std::make_pair(TIFFGetStrileOffset(tif, index), TIFFGetStrileByteCount(tif, index));
  TIFFClose(tif);
  return r;
}

void Overwrite(const std::string& path, uint64_t offset, const std::string& bytes) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(static_cast<std::streamoff>(offset));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Sets the value of a LONG/SHORT tag in IFD 0 of a little-endian BigTIFF.
void PatchTag(const std::string& path, uint16_t tag, uint32_t value) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  uint64_t ifd = 0, count = 0;
  f.seekg(8);
  f.read(reinterpret_cast<char*>(&ifd), 8);
  f.seekg(static_cast<std::streamoff>(ifd));
  f.read(reinterpret_cast<char*>(&count), 8);
  for (uint64_t i = 0; i < count; ++i) {
    const auto entry = static_cast<std::streamoff>(ifd + 8 + i * 20);
    uint16_t t = 0, type = 0;
    f.seekg(entry);
    f.read(reinterpret_cast<char*>(&t), 2);
    f.read(reinterpret_cast<char*>(&type), 2);
    if (t != tag) continue;
    f.seekp(entry + 12);
    if (type == TIFF_SHORT) {
      uint16_t v = static_cast<uint16_t>(value);
      f.write(reinterpret_cast<char*>(&v), 2);
    } else {
      f.write(reinterpret_cast<char*>(&value), 4);
    }
    return;
  }
  ADD_FAILURE() << "tag " << tag << " not found";
}

TEST(TiledImage, ReadsAnyLevelAndScale) {
  ScratchDir dir;
  const std::string path = WriteSample(dir, Compression::kZstd, 2000, 1600);
  TiledImage t = TiledImage::Open(path, std::make_shared<TileCache>());
  ASSERT_EQ(t.num_levels(), 4);  // 2000, 1000, 500, 250
  EXPECT_EQ(t.LevelForScale(1.0), 0);
  EXPECT_EQ(t.LevelForScale(0.5), 1);
  EXPECT_EQ(t.LevelForScale(0.3), 1);
  EXPECT_EQ(t.LevelForScale(0.25), 2);
  EXPECT_EQ(t.LevelForScale(0.01), 3);
  // Scale 0.5 of a region equals that region of level 1 exactly (even offsets).
  cv::Mat direct = t.ReadRegion(1, cv::Rect(100, 50, 300, 200));
  cv::Mat scaled = t.ReadScaled(cv::Rect(200, 100, 600, 400), 0.5);
  ASSERT_EQ(scaled.size(), direct.size());
  EXPECT_EQ(cv::norm(scaled, direct, cv::NORM_INF), 0.0);
  // Any scale: close to area averaging of level 0.
  cv::Rect r(333, 222, 900, 700);
  cv::Mat s = t.ReadScaled(r, 0.37);
  cv::Mat expected;
  cv::resize(t.ReadRegion(0, r), expected, s.size(), 0, 0, cv::INTER_AREA);
  EXPECT_GE(test::Psnr(s, expected), 28.0);
  // Bands read with ReadResampled join without seams: two halves equal one whole.
  cv::Mat whole = t.ReadResampled(100, 100, 0.3, cv::Size(300, 200));
  cv::Mat top = t.ReadResampled(100, 100, 0.3, cv::Size(300, 100));
  cv::Mat bottom = t.ReadResampled(100, 100 + 100 / 0.3, 0.3, cv::Size(300, 100));
  cv::Mat joined;
  cv::vconcat(top, bottom, joined);
  EXPECT_LE(cv::norm(joined, whole, cv::NORM_INF), 2.0);
}

TEST(TiledImage, ReadsGdalCogAndPlainImages) {
  if (!test::HaveCommand("gdal_translate")) GTEST_SKIP() << "gdal_translate not installed";
  ScratchDir dir;
  cv::Mat image = MakeImage(1200, 900);
  cv::imwrite(dir / "plain.png", image);
  auto r = test::RunShell("gdal_translate -q -of COG -co COMPRESS=DEFLATE -co BLOCKSIZE=256 " +
                          (dir / "plain.png") + " " + (dir / "cog.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto cache = std::make_shared<TileCache>();
  TiledImage cog = TiledImage::Open(dir / "cog.tif", cache);
  EXPECT_GE(cog.num_levels(), 3);
  EXPECT_EQ(cv::norm(cog.ReadRegion(0, cv::Rect(0, 0, 1200, 900)), image, cv::NORM_INF), 0.0);
  cv::Mat level1 = cog.ReadRegion(1, cv::Rect(0, 0, 600, 450));
  EXPECT_EQ(level1.size(), cv::Size(600, 450));
  TiledImage png = TiledImage::Open(dir / "plain.png", cache);
  EXPECT_EQ(png.num_levels(), 1);
  EXPECT_EQ(cv::norm(png.ReadRegion(0, cv::Rect(10, 20, 500, 400)), image(cv::Rect(10, 20, 500, 400)),
                     cv::NORM_INF), 0.0);
}

// Tiled TIFFs are decoded by libtiff directly: the pixels are GDAL's own, bit for bit, in every
// colour model and depth the fast path takes (JPEG in YCbCr, 16-bit grey, RGBA), at every level.
TEST(TiledImage, TiffTilesReadAsGdalReadsThem) {
  if (!test::HaveCommand("gdal_translate")) GTEST_SKIP() << "gdal_translate not installed";
  ScratchDir dir;
  cv::imwrite(dir / "rgb.png", MakeImage(700, 530));
  cv::Mat grey16 = MakeImage(650, 470, 1, 16);
  cv::imwrite(dir / "grey16.png", grey16);
  cv::imwrite(dir / "rgba.png", MakeImage(600, 450, 4));
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"rgb.png", "-of COG -co COMPRESS=JPEG -co QUALITY=85 -co BLOCKSIZE=128"},
      {"rgb.png", "-of GTiff -co TILED=YES -co COMPRESS=JPEG -co PHOTOMETRIC=YCBCR -co BLOCKXSIZE=96 -co BLOCKYSIZE=64"},
      {"grey16.png", "-of COG -co COMPRESS=DEFLATE -co BLOCKSIZE=256"},
      {"rgba.png", "-of COG -co COMPRESS=WEBP -co QUALITY=90 -co BLOCKSIZE=128"},
  };
  auto cache = std::make_shared<TileCache>();
  int k = 0;
  for (const auto& [source, options] : cases) {
    const std::string tif = dir / ("case" + std::to_string(k++) + ".tif");
    auto r = test::RunShell("gdal_translate -q " + options + " " + (dir / source) + " " + tif);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    TiledImage t = TiledImage::Open(tif, cache);
    for (int level = 0; level < std::min(2, t.num_levels()); ++level) {
      const std::string png = tif + ".level" + std::to_string(level) + ".png";
      const std::string overview = level == 0 ? "" : " -oo OVERVIEW_LEVEL=" + std::to_string(level - 1);
      r = test::RunShell("gdal_translate -q -of PNG" + overview + " " + tif + " " + png);
      ASSERT_EQ(r.exit_code, 0) << r.output;
      const cv::Mat gdal = cv::imread(png, cv::IMREAD_UNCHANGED);
      const auto& l = t.info().levels[size_t(level)];
      ASSERT_EQ(gdal.size(), cv::Size(int(l.width), int(l.height))) << options;
      // The whole level, and a window across tile edges.
      EXPECT_EQ(cv::norm(t.ReadRegion(level, cv::Rect(0, 0, gdal.cols, gdal.rows)), gdal, cv::NORM_INF), 0.0)
          << options << " level " << level;
      const cv::Rect w(gdal.cols / 3, gdal.rows / 4, gdal.cols / 2, gdal.rows / 2);
      EXPECT_EQ(cv::norm(t.ReadRegion(level, w), gdal(w), cv::NORM_INF), 0.0) << options << " level " << level;
    }
    // Through libtiff, not OpenImageIO: the cache's own tiles hold them.
    EXPECT_EQ(cache->Stats().find("decoded tiles (libtiff): 0 held"), std::string::npos) << options;
    cache->Invalidate(tif);
    EXPECT_EQ(cache->Stats().rfind("decoded tiles (libtiff): 0 held", 0), 0u) << options;
  }
}

// A tile the file does not hold (GDAL's SPARSE_OK, a writer stopped early) reads as zeros.
TEST(TiledImage, TilesTheFileDoesNotHoldReadAsZeros) {
  ScratchDir dir;
  const std::string path = dir / "sparse.tif";
  TIFF* tif = TIFFOpen(path.c_str(), "w8");
  ASSERT_NE(tif, nullptr);
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 128);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 128);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
  TIFFSetField(tif, TIFFTAG_TILEWIDTH, 64);
  TIFFSetField(tif, TIFFTAG_TILELENGTH, 64);
  cv::Mat tile(64, 64, CV_8U, cv::Scalar(200));
  ASSERT_GT(TIFFWriteEncodedTile(tif, 0, tile.data, 64 * 64), 0);  // only the first of four
  TIFFClose(tif);
  TiledImage t = TiledImage::Open(path, std::make_shared<TileCache>());
  const cv::Mat all = t.ReadRegion(0, cv::Rect(0, 0, 128, 128));
  EXPECT_EQ(cv::countNonZero(all(cv::Rect(0, 0, 64, 64)) == 200), 64 * 64);
  EXPECT_EQ(cv::countNonZero(all(cv::Rect(64, 0, 64, 128))), 0);
  EXPECT_EQ(cv::countNonZero(all(cv::Rect(0, 64, 64, 64))), 0);
}

// A file deleted or replaced while it is open (a live preview superseded, a mosaic composed
// anew) goes on reading as it was: the tiles decoded on both cores wait for the handle the image
// holds instead of failing to open the file again.
TEST(TiledImage, AFileDeletedWhileOpenStillReadsAsItWas) {
  ScratchDir dir;
  const std::string path = WriteSample(dir, Compression::kZstd, 1500, 1100);
  TiledImage first = TiledImage::Open(path, std::make_shared<TileCache>());
  const cv::Mat level0 = first.ReadRegion(0, cv::Rect(0, 0, 1500, 1100));
  const cv::Mat level1 = first.ReadRegion(1, cv::Rect(0, 0, 750, 550));
  TiledImage t = TiledImage::Open(path, std::make_shared<TileCache>());
  std::filesystem::remove(path);
  EXPECT_EQ(cv::norm(t.ReadRegion(0, cv::Rect(0, 0, 1500, 1100)), level0, cv::NORM_INF), 0.0);
  // Replaced by another image under the same name: still the first one's pixels.
  WritePyramidTiff(path, MakeImage(1500, 1100, 3, 8, 99), TiffWriteOptions{});
  EXPECT_EQ(cv::norm(t.ReadRegion(1, cv::Rect(0, 0, 750, 550)), level1, cv::NORM_INF), 0.0);
}

TEST(TiledImage, RegionOutsideTheImageIsAnError) {
  ScratchDir dir;
  TiledImage t = TiledImage::Open(WriteSample(dir, Compression::kDeflate), std::make_shared<TileCache>());
  EXPECT_NE(ErrorOf([&] { t.ReadRegion(0, cv::Rect(1400, 0, 200, 10)); }).find("outside level 0"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { t.ReadRegion(0, cv::Rect(-1, 0, 10, 10)); }).find("outside"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { t.ReadRegion(9, cv::Rect(0, 0, 10, 10)); }).find("level 9 does not exist"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { t.ReadScaled(cv::Rect(0, 0, 10, 10), 2.0); }).find("scale"),
            std::string::npos);
}

TEST(TiledImage, MissingNotAnImageAndDirectoryAreClearErrors) {
  ScratchDir dir;
  EXPECT_NE(ErrorOf([&] { TiledImage::Open(dir / "nope.tif"); }).find("no such file"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { TiledImage::Open(dir.path()); }).find("is a directory"),
            std::string::npos);
  std::ofstream(dir / "text.tif") << "this is not a tiff";
  EXPECT_NE(ErrorOf([&] { TiledImage::Open(dir / "text.tif"); }).find("text.tif"),
            std::string::npos);
  std::ofstream(dir / "empty.tif");
  EXPECT_NE(ErrorOf([&] { TiledImage::Open(dir / "empty.tif"); }).find("empty.tif"),
            std::string::npos);
}

TEST(TiledImage, TruncatedFileIsFoundAtOpen) {
  ScratchDir dir;
  const std::string path = WriteSample(dir, Compression::kJpeg);
  // Cut into level 0's tiles (the reduced levels' IFDs go with them: keep only 60 %).
  const auto size = std::filesystem::file_size(path);
  std::filesystem::resize_file(path, size * 6 / 10);
  const std::string e = ErrorOf([&] { TiledImage::Open(path, std::make_shared<TileCache>()); });
  EXPECT_NE(e.find(path), std::string::npos) << e;
  EXPECT_NE(e.find("truncated"), std::string::npos) << e;
  // Truncated inside the header.
  std::filesystem::resize_file(path, 10);
  EXPECT_NE(ErrorOf([&] { TiledImage::Open(path); }).find(path), std::string::npos);
}

TEST(TiledImage, GarbageTileIsADecodeErrorNamingFileAndRegion) {
  for (Compression c : {Compression::kZstd, Compression::kDeflate, Compression::kJpeg}) {
    ScratchDir dir;
    const std::string path = WriteSample(dir, c);
    auto [offset, size] = TileBytes(path, 7);
    ASSERT_GT(size, 64u);
    std::mt19937 rng(7);
    std::string garbage(static_cast<size_t>(size), '\0');
    for (auto& ch : garbage) ch = static_cast<char>(rng());
    Overwrite(path, offset, garbage);
    TiledImage t = TiledImage::Open(path, std::make_shared<TileCache>());
    // Tile 7 is the 8th of the first row: x 1792.. (tile 256) -> beyond 1500? use row layout.
    const int tiles_x = (1500 + 255) / 256;
    const int tx = 7 % tiles_x, ty = 7 / tiles_x;
    const std::string e =
        ErrorOf([&] { t.ReadRegion(0, cv::Rect(tx * 256, ty * 256, 100, 100)); });
    EXPECT_NE(e.find(path), std::string::npos) << CompressionName(c) << ": " << e;
    EXPECT_NE(e.find("cannot be decoded"), std::string::npos) << CompressionName(c) << ": " << e;
    // The rest of the file still reads.
    EXPECT_NO_THROW(t.ReadRegion(0, cv::Rect(0, 0, 100, 100)));
  }
}

TEST(TiledImage, AbsurdDimensionsAreRefusedBeforeAnyAllocation) {
  ScratchDir dir;
  const std::string path = WriteSample(dir, Compression::kDeflate);
  PatchTag(path, TIFFTAG_IMAGEWIDTH, 0xF0000000u);
  std::string e = ErrorOf([&] { TiledImage::Open(path, std::make_shared<TileCache>()); });
  EXPECT_NE(e.find(path), std::string::npos) << e;
  EXPECT_FALSE(e.empty());
  const std::string path2 = WriteSample(dir, Compression::kZstd);
  PatchTag(path2, TIFFTAG_IMAGEWIDTH, 0);
  e = ErrorOf([&] { TiledImage::Open(path2, std::make_shared<TileCache>()); });
  EXPECT_NE(e.find(path2), std::string::npos) << e;
  const std::string path3 = WriteSample(dir, Compression::kNone);
  PatchTag(path3, TIFFTAG_TILEWIDTH, 1u << 20);
  e = ErrorOf([&] { TiledImage::Open(path3, std::make_shared<TileCache>()); });
  EXPECT_NE(e.find(path3), std::string::npos) << e;
}

}  // namespace
}  // namespace rolamos
