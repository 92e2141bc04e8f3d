#include "input/jpeg_reader.h"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "input/frame_source.h"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

int DifferentPixels(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return -1;
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  return cv::countNonZero(diff.reshape(1));
}

std::vector<unsigned char> FileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<unsigned char>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void WriteBytes(const std::string& path, const std::vector<unsigned char>& bytes) {
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

// An APP1 marker with EXIF whose first directory holds one orientation (little- or big-endian).
std::vector<unsigned char> ExifApp1(int orientation, bool big_endian) {
  auto u16 = [&](std::vector<unsigned char>* v, unsigned x) {
    if (big_endian) v->insert(v->end(), {static_cast<unsigned char>(x >> 8), static_cast<unsigned char>(x)});
    else v->insert(v->end(), {static_cast<unsigned char>(x), static_cast<unsigned char>(x >> 8)});
  };
  auto u32 = [&](std::vector<unsigned char>* v, unsigned x) {
    if (big_endian) { u16(v, x >> 16); u16(v, x & 0xFFFF); }
    else { u16(v, x & 0xFFFF); u16(v, x >> 16); }
  };
  std::vector<unsigned char> p = {'E', 'x', 'i', 'f', 0, 0};
  p.insert(p.end(), big_endian ? std::initializer_list<unsigned char>{'M', 'M'} : std::initializer_list<unsigned char>{'I', 'I'});
  u16(&p, 42);
  u32(&p, 8);     // the first directory, right after the header
  u16(&p, 1);     // one entry
  u16(&p, 0x0112);
  u16(&p, 3);     // SHORT
  u32(&p, 1);
  u16(&p, static_cast<unsigned>(orientation));
  u16(&p, 0);
  u32(&p, 0);     // no next directory
  std::vector<unsigned char> marker = {0xFF, 0xE1, static_cast<unsigned char>((p.size() + 2) >> 8),
                                       static_cast<unsigned char>((p.size() + 2) & 0xFF)};
  marker.insert(marker.end(), p.begin(), p.end());
  return marker;
}

// Frames of odd and even sizes, at the qualities cameras and the synthesiser write: the same
// pixels as cv::imread, to the last bit.
TEST(JpegReader, GivesCvImreadsPixels) {
  const test::ScratchDir dir;
  const cv::Size sizes[] = {{800, 600}, {641, 479}, {37, 23}};
  int n = 0;
  for (const cv::Size size : sizes)
    for (int quality : {75, 95}) {
      cv::Mat frame = RenderSeafloor(n * 97, n * 31, size.width, size.height);
      if (frame.channels() == 1) cv::cvtColor(frame, frame, cv::COLOR_GRAY2BGR);
      // Some colour, so that a swapped channel shows.
      cv::Mat tint(frame.size(), CV_8UC3, cv::Scalar(40, 0, 90));
      cv::add(frame, tint, frame);
      const std::string path = dir / ("f" + std::to_string(n++) + ".jpg");
      ASSERT_TRUE(cv::imwrite(path, frame, {cv::IMWRITE_JPEG_QUALITY, quality}));
      cv::Mat ours;
      ASSERT_TRUE(ReadJpegBgr(path, &ours)) << path;
      const cv::Mat theirs = cv::imread(path, cv::IMREAD_COLOR);
      EXPECT_EQ(DifferentPixels(ours, theirs), 0) << size << " at quality " << quality;
    }
}

// The real camera photos, EXIF and all, where the data is present.
TEST(JpegReader, GivesCvImreadsPixelsOnCameraPhotos) {
  const std::string data = test::SharedData();
  if (data.empty()) GTEST_SKIP() << "../shared/data is absent";
  int seen = 0;
  for (const auto& e : std::filesystem::directory_iterator(data + "/seattle_rov_gopro_large")) {
    if (e.path().extension() != ".JPG" || seen == 2) continue;
    ++seen;
    cv::Mat ours;
    const cv::Mat theirs = cv::imread(e.path().string(), cv::IMREAD_COLOR);
    if (ReadJpegBgr(e.path().string(), &ours)) EXPECT_EQ(DifferentPixels(ours, theirs), 0) << e.path();
    // Either way, a frame read from the file is cv::imread's.
    std::atomic<int> bits{8};
    std::string error;
    EXPECT_EQ(DifferentPixels(ReadFrameImage(e.path().string(), &bits, &error), theirs), 0) << e.path();
  }
  if (seen == 0) GTEST_SKIP() << "no camera photos in the data";
}

// What it leaves to cv::imread: grey JPEGs, a turn in EXIF (cv::imread turns the image), files
// that are not JPEGs or are cut off; ReadFrameImage then reads them as before.
TEST(JpegReader, LeavesOtherKindsToCvImread) {
  const test::ScratchDir dir;
  cv::Mat frame(60, 80, CV_8UC3, cv::Scalar(30, 90, 200));
  cv::rectangle(frame, cv::Rect(5, 5, 20, 40), cv::Scalar(250, 250, 10), cv::FILLED);
  const std::string colour = dir / "colour.jpg", grey = dir / "grey.jpg";
  ASSERT_TRUE(cv::imwrite(colour, frame));
  cv::Mat gray;
  cv::cvtColor(frame, gray, cv::COLOR_BGR2GRAY);
  ASSERT_TRUE(cv::imwrite(grey, gray));
  cv::Mat out;
  EXPECT_TRUE(ReadJpegBgr(colour, &out));
  EXPECT_FALSE(ReadJpegBgr(grey, &out));
  EXPECT_TRUE(out.empty());

  // The same colour frame with EXIF: upright (1) is decoded here, turned (6) is not.
  const std::vector<unsigned char> bytes = FileBytes(colour);
  for (bool big : {false, true})
    for (int orientation : {1, 6}) {
      std::vector<unsigned char> with(bytes.begin(), bytes.begin() + 2);  // SOI
      const auto app1 = ExifApp1(orientation, big);
      with.insert(with.end(), app1.begin(), app1.end());
      with.insert(with.end(), bytes.begin() + 2, bytes.end());
      const std::string path = dir / ("exif" + std::to_string(orientation) + (big ? "m" : "i") + ".jpg");
      WriteBytes(path, with);
      EXPECT_EQ(ExifOrientation(app1.data() + 4, app1.size() - 4), orientation);
      EXPECT_EQ(ReadJpegBgr(path, &out), orientation == 1) << path;
      std::atomic<int> bits{8};
      std::string error;
      const cv::Mat read = ReadFrameImage(path, &bits, &error);
      EXPECT_EQ(DifferentPixels(read, cv::imread(path, cv::IMREAD_COLOR)), 0) << path;
      if (orientation == 6) EXPECT_EQ(read.size(), cv::Size(60, 80));  // turned a quarter, as cv::imread does
    }

  // Not a JPEG at all: not decoded here. One cut short: filled in with grey as cv::imread fills
  // it (libjpeg warns); ReadFrameImage refuses both and says why.
  const std::string text = dir / "text.jpg", cut = dir / "cut.jpg";
  std::ofstream(text) << "not a jpeg";
  WriteBytes(cut, std::vector<unsigned char>(bytes.begin(), bytes.begin() + long(bytes.size() / 2)));
  EXPECT_FALSE(ReadJpegBgr(text, &out));
  if (ReadJpegBgr(cut, &out)) EXPECT_EQ(DifferentPixels(out, cv::imread(cut, cv::IMREAD_COLOR)), 0);
  // The end-marker check reads the bytes the decoder would have read.
  for (const auto& [path, reason] : {std::pair<std::string, std::string>{text, "unreadable"}, {cut, "truncated"}}) {
    std::atomic<int> bits{8};
    std::string error;
    EXPECT_TRUE(ReadFrameImage(path, &bits, &error).empty());
    EXPECT_EQ(error.rfind(reason, 0), 0u) << path << ": " << error;
  }
  EXPECT_FALSE(ReadJpegBgr(dir / "missing.jpg", &out));
  EXPECT_EQ(ExifOrientation(reinterpret_cast<const unsigned char*>("JFIF\0"), 5), 0);
}

}  // namespace
}  // namespace rolamos
