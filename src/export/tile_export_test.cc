// Static tile export: every tile of every level written, the same pixels the store holds, a
// Deep Zoom descriptor OpenSeadragon reads, and no half-written directory on failure.
#include "rolamos/tile_export.hpp"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

long long CountFiles(const std::string& dir, const std::string& ext) {
  long long n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    n += e.is_regular_file() && e.path().extension() == ext;
  return n;
}

TEST(TileExport, XyzAndDeepZoomHoldEveryTileWithTheStoredPixels) {
  test::ScratchDir dir;
  ASSERT_EQ(test::RunCli("demo -q --size 1500 --compression zstd -o " + (dir / "d.rolamos")).exit_code, 0);
  Store store = Store::Open(dir / "d.rolamos");
  TileExportOptions xyz;
  xyz.format = "xyz";
  xyz.ext = "png";
  TileExportResult r = ExportTiles(store, dir / "xyz", xyz);
  // 1500 px: zoom 0..3 = 188, 375, 750, 1500 px -> 1 + 4 + 9 + 36 tiles.
  EXPECT_EQ(r.tiles, 50);
  EXPECT_EQ(CountFiles(dir / "xyz/patch-1", ".png"), 50);  // (the map page brings images of its own)
  // XYZ tiles are whole 256 x 256 tiles, colour as stored and alpha 255 where the image is.
  cv::Mat tile = cv::imread(dir / "xyz/patch-1/3/1/2.png", cv::IMREAD_UNCHANGED);
  ASSERT_EQ(tile.type(), CV_8UC4);
  TiledImage image = TiledImage::Open(store.PatchImagePath(1));
  cv::Mat stored = image.ReadRegion(0, cv::Rect(256, 512, 256, 256)), colour, alpha;
  cv::cvtColor(tile, colour, cv::COLOR_BGRA2BGR);
  cv::extractChannel(tile, alpha, 3);
  if (stored.channels() == 4) cv::cvtColor(stored, stored, cv::COLOR_BGRA2BGR);
  EXPECT_EQ(cv::norm(colour, stored, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::countNonZero(alpha == 255), 256 * 256);
  // The edge tile and zoom 0: whole, transparent past the image (1500 = 5 * 256 + 220; 188 at zoom 0).
  const cv::Mat edge = cv::imread(dir / "xyz/patch-1/3/5/5.png", cv::IMREAD_UNCHANGED);
  ASSERT_EQ(edge.size(), cv::Size(256, 256));
  cv::extractChannel(edge, alpha, 3);
  EXPECT_EQ(cv::countNonZero(alpha), 220 * 220);
  EXPECT_EQ(cv::imread(dir / "xyz/patch-1/0/0/0.png").size(), cv::Size(256, 256));
  EXPECT_TRUE(fs::exists(dir / "xyz/patch-1.xml"));  // GDAL WMS (TMS) description

  TileExportResult d = ExportTiles(store, dir / "dzi", TileExportOptions{});
  EXPECT_EQ(CountFiles(dir / "dzi", ".jpg"), d.tiles);
  EXPECT_GT(d.tiles, 50);  // levels 0..11 (down to one pixel)
  std::ifstream dzi(dir / "dzi/patch-1.dzi");
  std::string text((std::istreambuf_iterator<char>(dzi)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("Width=\"1500\" Height=\"1500\""), std::string::npos);
  EXPECT_EQ(cv::imread(dir / "dzi/patch-1_files/0/0_0.jpg").size(), cv::Size(1, 1));
  EXPECT_TRUE(fs::exists(dir / "dzi/images.json"));
}

TEST(TileExport, RefusesExistingDirectoriesAndBadOptions) {
  test::ScratchDir dir;
  ASSERT_EQ(test::RunCli("demo -q --size 300 -o " + (dir / "d.rolamos")).exit_code, 0);
  Store store = Store::Open(dir / "d.rolamos");
  fs::create_directories(dir / "taken");
  EXPECT_NE(test::ErrorOf([&] { ExportTiles(store, dir / "taken", TileExportOptions{}); }).find("exists"),
            std::string::npos);
  TileExportOptions bad;
  bad.format = "tms";
  EXPECT_NE(test::ErrorOf([&] { ExportTiles(store, dir / "t", bad); }).find("tms"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir / "t"));
}

}  // namespace
}  // namespace rolamos
