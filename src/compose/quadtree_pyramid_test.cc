// The chunked, resumable pyramid builder against the band writer: the same pixels on every level,
// whatever the chunking, and an interrupted build finished by a second run is the same file.
#include "compose/quadtree_pyramid.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"
#include "compose/tile_journal.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;
using test::ScratchDir;

// BGRA with a transparent hole and a transparent right part, odd sizes.
cv::Mat TestImage(int w, int h) {
  cv::Mat bgra;
  cv::cvtColor(test::MakeImage(w, h, 3, 8), bgra, cv::COLOR_BGR2BGRA);
  cv::rectangle(bgra, cv::Rect(w / 3, h / 3, w / 5, h / 4), cv::Scalar::all(0), cv::FILLED);
  bgra.colRange(w - w / 4, w).setTo(cv::Scalar::all(0));
  return bgra;
}

RenderFn CropOf(const cv::Mat& image, std::atomic<int>* calls = nullptr) {
  return [&image, calls](const cv::Rect& r) {
    if (calls) ++*calls;
    cv::Mat block = image(r).clone();
    std::vector<cv::Mat> ch;
    cv::split(block, ch);
    return cv::countNonZero(ch[3]) ? block : cv::Mat();
  };
}

PixelLayout LayoutOf(const cv::Mat& image) {
  PixelLayout l;
  l.width = image.cols;
  l.height = image.rows;
  l.channels = 4;
  return l;
}

void ExpectSameLevels(const std::string& a, const std::string& b) {
  auto cache = std::make_shared<TileCache>();
  TiledImage x = TiledImage::Open(a, cache), y = TiledImage::Open(b, cache);
  ASSERT_EQ(x.num_levels(), y.num_levels());
  for (int k = 0; k < x.num_levels(); ++k) {
    const auto& L = x.info().levels[size_t(k)];
    ASSERT_EQ(L.width, y.info().levels[size_t(k)].width);
    const cv::Rect all(0, 0, static_cast<int>(L.width), static_cast<int>(L.height));
    cv::Mat d;
    cv::absdiff(x.ReadRegion(k, all), y.ReadRegion(k, all), d);
    EXPECT_EQ(cv::countNonZero(d.reshape(1)), 0) << "level " << k;
  }
}

TEST(QuadtreePyramid, SameLevelsAsTheBandWriterForAnyChunking) {
  ScratchDir dir;
  const cv::Mat image = TestImage(1333, 777);
  TiffWriteOptions o;
  o.compression = Compression::kZstd;  // lossless: any difference is a real one
  WritePyramidTiff((dir / "bands.tif"), image, o);
  for (int chunk : {256, 512, 4096}) {
    for (int threads : {1, 2}) {
      QuadtreeOptions q;
      q.chunk_px = chunk;
      q.block_px = 256;
      q.threads = threads;
      const std::string out = dir / ("tree" + std::to_string(chunk) + ".tif");
      TileJournal journal((dir / "partial"), "test", /*restart=*/true);
      const QuadtreeStats s = BuildQuadtreePyramid(out, LayoutOf(image), o, q, CropOf(image), journal, nullptr);
      journal.Remove();
      EXPECT_EQ(s.chunks_resumed, 0);
      EXPECT_GE(s.chunks, 1);
      SCOPED_TRACE("chunk " + std::to_string(chunk));
      ExpectSameLevels((dir / "bands.tif"), out);
    }
  }
}

TEST(QuadtreePyramid, EmptyRegionsAreNotRenderedTwice) {
  ScratchDir dir;
  const cv::Mat image(700, 1100, CV_8UC4, cv::Scalar::all(0));  // nothing at all
  QuadtreeOptions q;
  q.chunk_px = 512;
  q.block_px = 512;
  std::atomic<int> calls{0};
  TileJournal journal((dir / "partial"), "test", true);
  BuildQuadtreePyramid((dir / "empty.tif"), LayoutOf(image), TiffWriteOptions{}, q,
                       CropOf(image, &calls), journal, nullptr);
  EXPECT_EQ(calls, 3 * 2);  // one render per 512 block
  TiledImage t = TiledImage::Open((dir / "empty.tif"), std::make_shared<TileCache>());
  EXPECT_EQ(cv::countNonZero(t.ReadRegion(0, cv::Rect(0, 0, 1100, 700)).reshape(1)), 0);
}

TEST(QuadtreePyramid, AnInterruptedBuildResumesToTheSameFile) {
  ScratchDir dir;
  const cv::Mat image = TestImage(2100, 1500);
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  QuadtreeOptions q;
  q.chunk_px = 256;
  q.threads = 2;
  const std::string partial = (dir / "partial");
  const std::string out = (dir / "out.tif");
  long long chunks = 0;
  {
    TileJournal journal(partial, "inputs-1", false);
    int reports = 0;
    auto stop = [&](double) {
      if (++reports == 8) throw Error("interrupted");
    };
    EXPECT_THROW(BuildQuadtreePyramid(out, LayoutOf(image), o, q, CropOf(image), journal, stop), Error);
    chunks = journal.chunks_done();
    EXPECT_GT(chunks, 0);
  }
  EXPECT_FALSE(fs::exists(out));  // nothing half-written under the final name
  // A crash in the middle of a journal line leaves a line without its end: ignored.
  { std::ofstream(partial + "/journal.txt", std::ios::app) << "chunk 99 2 0,1,0,5"; }
  std::atomic<int> calls{0};
  {
    TileJournal journal(partial, "inputs-1", false);
    EXPECT_TRUE(journal.discarded().empty());
    EXPECT_EQ(journal.chunks_done(), chunks);
    const QuadtreeStats s = BuildQuadtreePyramid(out, LayoutOf(image), o, q, CropOf(image, &calls), journal, nullptr);
    EXPECT_EQ(s.chunks_resumed, chunks);
    EXPECT_EQ(calls, s.chunks - chunks);  // block = chunk here: only the rest was rendered
  }
  const std::string fresh = (dir / "fresh.tif");
  {
    TileJournal journal(partial, "inputs-2", false);  // other inputs: not resumed
    EXPECT_FALSE(journal.discarded().empty());
    EXPECT_EQ(journal.chunks_done(), 0);
    BuildQuadtreePyramid(fresh, LayoutOf(image), o, q, CropOf(image), journal, nullptr);
    journal.Remove();
  }
  EXPECT_FALSE(fs::exists(partial));
  ExpectSameLevels(fresh, out);
}

// Writing the TIFF frees the journal's copies: a run that died then must start over, not read
// holes as tiles.
TEST(QuadtreePyramid, AJournalThatWasBeingAssembledIsStartedOver) {
  ScratchDir dir;
  const cv::Mat image = TestImage(700, 600);
  QuadtreeOptions q;
  q.chunk_px = 256;
  const std::string partial = dir / "partial";
  {
    TileJournal journal(partial, "same", false);
    BuildQuadtreePyramid(dir / "out.tif", LayoutOf(image), TiffWriteOptions{}, q, CropOf(image), journal, nullptr);
    EXPECT_GT(journal.chunks_done(), 1);
  }  // as if it died before Remove()
  TileJournal again(partial, "same", false);
  EXPECT_NE(again.discarded().find("already writing"), std::string::npos) << again.discarded();
  EXPECT_EQ(again.chunks_done(), 0);
}

TEST(QuadtreePyramid, ADamagedJournalIsStartedOver) {
  ScratchDir dir;
  const std::string partial = (dir / "partial");
  fs::create_directories(partial);
  { std::ofstream(partial + "/journal.txt") << "\x01\x02 not a journal\n"; }
  TileJournal journal(partial, "x", false);
  EXPECT_NE(journal.discarded().find("unreadable"), std::string::npos);
  EXPECT_EQ(journal.chunks_done(), 0);
  EXPECT_THROW(journal.Read(0, 0), Error);
}

}  // namespace
}  // namespace rolamos
