#include "raster/decoded_tiles.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "test_support.h"

namespace rolamos {
namespace {

std::shared_ptr<const cv::Mat> Tile(int value) {
  return std::make_shared<const cv::Mat>(64, 64, CV_8U, cv::Scalar(value));  // 4 KB
}

// Within its byte limit the least recently used tile goes first; a tile read again stays.
TEST(DecodedTiles, DropsTheLeastRecentlyUsedBeyondItsLimit) {
  DecodedTiles tiles(3 * 4096);
  tiles.Add(1, 0, 0, 0, Tile(1));
  tiles.Add(1, 0, 1, 0, Tile(2));
  tiles.Add(1, 0, 2, 0, Tile(3));
  ASSERT_TRUE(tiles.Find(1, 0, 0, 0));  // used again: now the newest
  tiles.Add(1, 0, 3, 0, Tile(4));
  EXPECT_EQ(tiles.bytes(), 3u * 4096);
  EXPECT_TRUE(tiles.Find(1, 0, 0, 0));
  EXPECT_FALSE(tiles.Find(1, 0, 1, 0));  // the oldest unused
  EXPECT_EQ(tiles.Find(1, 0, 3, 0)->at<uchar>(0, 0), 4);
  EXPECT_FALSE(tiles.Find(2, 0, 3, 0));  // another file
  EXPECT_FALSE(tiles.Find(1, 1, 3, 0));  // another level
}

// A file rewritten is a new file: its old tiles are never served for it; Forget drops them.
TEST(DecodedTiles, ARewrittenFileIsANewFile) {
  test::ScratchDir dir;
  const std::string path = dir / "f.tif";
  std::ofstream(path) << "one";
  DecodedTiles tiles(1 << 20);
  const uint64_t first = tiles.FileId(path, FileStamp::Of(path));
  EXPECT_EQ(tiles.FileId(path, FileStamp::Of(path)), first);
  tiles.Add(first, 0, 0, 0, Tile(1));
  std::ofstream(dir / "g.tif") << "two, longer";
  std::filesystem::rename(dir / "g.tif", path);
  const uint64_t second = tiles.FileId(path, FileStamp::Of(path));
  EXPECT_NE(second, first);
  EXPECT_FALSE(tiles.Find(second, 0, 0, 0));
  EXPECT_EQ(tiles.files(), 2u);
  tiles.Forget(path);
  EXPECT_EQ(tiles.bytes(), 0u);
  EXPECT_EQ(tiles.files(), 0u);  // nothing kept of a file forgotten
}

}  // namespace
}  // namespace rolamos
