#include "input/overlay_search.h"

#include <atomic>
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/store.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

// A dive as an ROV films it: `water` frames of open water (flat), then the seafloor moving under
// the camera; every frame carries the same burned-in mark.
void WriteDive(const std::string& dir, int water, int seafloor) {
  const cv::Mat ground = RenderSeafloor(0, 0, 2000, 800);
  for (int i = 0; i < water + seafloor; ++i) {
    cv::Mat frame;
    if (i < water) {
      frame = cv::Mat(360, 480, CV_8UC3, cv::Scalar(120, 100, 40));
    } else {
      const int k = i - water;
      frame = ground(cv::Rect(40 * k, 15 * k % 400, 480, 360)).clone();
    }
    cv::circle(frame, {240, 180}, 14, cv::Scalar(255, 255, 255), cv::FILLED);
    char name[32];
    std::snprintf(name, sizeof name, "/f%03d.png", i);
    cv::imwrite(dir + name, frame);
  }
}

TEST(OverlaySearch, ADescentThroughOpenWaterDoesNotHideTheOverlay) {
  const test::ScratchDir dir;
  WriteDive(dir.path(), 40, 36);
  std::vector<cv::Mat> first;
  for (int i = 0; i < 24; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "/f%03d.png", i);
    first.push_back(cv::imread(dir.path() + name));
  }
  // The first frames alone cannot tell: only the mark has edges.
  const StaticMask alone = FindOverlay(first, MosaickerOptions());
  EXPECT_FALSE(alone.conclusive) << alone.note;
  EXPECT_TRUE(alone.mask.empty());
  // Further on, once the seafloor moves under the mark, it is found.
  const StaticMask found = SearchOverlayFurther(dir.path(), 24, MosaickerOptions());
  ASSERT_TRUE(found.conclusive) << found.note;
  ASSERT_FALSE(found.mask.empty()) << found.note;
  EXPECT_GT(found.mask.at<uchar>(180, 240), 0);
  EXPECT_EQ(found.mask.at<uchar>(20, 20), 0);
  EXPECT_NE(found.note.find("the first 24 could not tell"), std::string::npos) << found.note;
  // No further than asked, and nothing once stopped; a long search says how far it has read.
  OverlaySearchOptions short_search;
  short_search.max_frames = 40;  // all open water
  short_search.progress_every = 10;
  std::vector<int> heard;
  short_search.progress = [&](int read) { heard.push_back(read); };
  EXPECT_FALSE(SearchOverlayFurther(dir.path(), 24, MosaickerOptions(), short_search).conclusive);
  EXPECT_EQ(heard, (std::vector<int>{10, 20, 30, 40}));
  const std::atomic<bool> stop{true};
  const StaticMask stopped = SearchOverlayFurther(dir.path(), 24, MosaickerOptions(), {}, &stop);
  EXPECT_FALSE(stopped.conclusive);
  EXPECT_NE(stopped.note.find("searched 0 frames"), std::string::npos) << stopped.note;
  // A run with `--mask auto` (the default) searches on, and its mask leaves the mark out.
  Store store = Store::Create(dir / "s.rolamos");
  MosaickerOptions o;
  o.mask = "auto";
  const MosaicSummary sum = MosaicInput(dir.path(), store, o);
  EXPECT_NE(sum.mask_note.find("the first 24 could not tell"), std::string::npos) << sum.mask_note;
  const cv::Mat written = cv::imread(dir / "s.rolamos/static_mask.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(written.empty());
  EXPECT_GT(written.at<uchar>(180, 240), 0);
  EXPECT_EQ(sum.stitched, 36);  // the seafloor's frames; open water has nothing to place
}

}  // namespace
}  // namespace rolamos
