#include "input/frame_source.h"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

// A folder's frames taken several at once (decoded in parallel) come in the order and with the
// numbers and reasons Next gives them, and Next goes on after them.
TEST(FrameSource, TakesSeveralFramesInOrderAndGoesOnAfterThem) {
  const test::ScratchDir dir;
  for (int i = 0; i < 6; ++i) {
    const std::string name = dir / ("f" + std::to_string(i) + ".png");
    if (i == 2) {
      std::ofstream(name) << "not a png";  // unreadable: comes back empty, with the reason
      continue;
    }
    cv::imwrite(name, cv::Mat(24, 32, CV_8UC3, cv::Scalar(10 * i, 0, 0)));
  }
  const auto source = FrameSource::Open(dir.path());
  std::vector<InputFrame> frames;
  EXPECT_EQ(source->Take(4, &frames), 4);
  InputFrame next;
  ASSERT_TRUE(source->Next(&next));
  EXPECT_EQ(next.index, 4);
  EXPECT_EQ(source->Take(10, &frames), 1);  // only one is left
  EXPECT_EQ(source->Take(3, &frames), 0);
  ASSERT_EQ(frames.size(), 5u);
  const int expected_index[] = {0, 1, 2, 3, 5};
  for (size_t k = 0; k < frames.size(); ++k) {
    const InputFrame& f = frames[k];
    EXPECT_EQ(f.index, expected_index[k]);
    EXPECT_NE(f.source.find("f" + std::to_string(f.index) + ".png"), std::string::npos) << f.source;
    if (f.index == 2) {
      EXPECT_TRUE(f.image.empty());
      EXPECT_FALSE(f.error.empty());
      continue;
    }
    ASSERT_FALSE(f.image.empty()) << f.source << ": " << f.error;
    EXPECT_EQ(f.image.at<cv::Vec3b>(0, 0)[0], 10 * f.index);
  }
}

// A list of frames as people and spreadsheets write them: comments, blank lines, blanks and tabs
// around names, Windows line ends, names relative to the list's folder, spaces inside names.
TEST(FrameSource, AListTakesItsNamesAsWrittenAroundBlanksAndComments) {
  const test::ScratchDir dir;
  for (const char* name : {"/a.png", "/b c.png", "/d.png"}) cv::imwrite(dir.path() + name, cv::Mat(8, 8, CV_8UC3));
  std::ofstream(dir / "frames.txt") << "# dive 12\n\n  a.png  \n\tb c.png\t\r\n" << (dir / "d.png") << "\r\n   \n";
  const auto source = FrameSource::Open(dir / "frames.txt");
  InputFrame f;
  for (const char* name : {"/a.png", "/b c.png", "/d.png"}) {
    ASSERT_TRUE(source->Next(&f)) << name;
    EXPECT_EQ(f.source, dir.path() + name);
    EXPECT_TRUE(f.error.empty()) << f.source << ": " << f.error;
  }
  EXPECT_FALSE(source->Next(&f));
}

// `ffmpeg -i dive.mp4 frame%d.jpg` numbers frames without leading zeros: by name, frame10 would
// come after frame1 and before frame2, and the survey would jump back and forth. Hidden files
// beside them are not frames.
TEST(FrameSource, AFoldersFramesComeInTheCamerasOrder) {
  const test::ScratchDir dir;
  for (int i = 1; i <= 12; ++i) {
    cv::imwrite(dir / ("frame" + std::to_string(i) + ".png"), cv::Mat(8, 8, CV_8UC3));
    // What macOS leaves beside each file it copies to a USB drive: hidden, not an image.
    std::ofstream(dir / ("._frame" + std::to_string(i) + ".png")) << "Mac OS X        ATTR";
  }
  const auto source = FrameSource::Open(dir.path());
  InputFrame f;
  for (int i = 1; i <= 12; ++i) {
    ASSERT_TRUE(source->Next(&f));
    EXPECT_NE(f.source.find("/frame" + std::to_string(i) + ".png"), std::string::npos) << f.source;
  }
  EXPECT_FALSE(source->Next(&f)) << "a hidden file taken as a frame: " << f.source;
}

// Machine-vision cameras write 10 or 12 bits of data in 16-bit PNGs and TIFFs. Read as OpenCV
// reads them (divided by 256), a 12-bit frame is black (0..15): every frame but a few rejected.
TEST(FrameSource, SixteenBitFramesAreScaledByTheDepthTheirValuesUse) {
  const test::ScratchDir dir;
  // A 12-bit camera's frames, grey and colour, the second darker than the first, then a frame
  // whose values need all 16 bits.
  cv::Mat grey(24, 32, CV_16UC1, cv::Scalar(2000)), colour(24, 32, CV_16UC3, cv::Scalar(4095, 1000, 300));
  grey.at<uint16_t>(0, 1) = 4000;
  cv::imwrite(dir / "f0.png", grey);
  cv::imwrite(dir / "f1.tif", colour);
  cv::imwrite(dir / "f2.png", cv::Mat(24, 32, CV_16UC1, cv::Scalar(60000)));
  cv::imwrite(dir / "f3.png", cv::Mat(24, 32, CV_8UC3, cv::Scalar(7, 8, 9)));
  const auto source = FrameSource::Open(dir.path());
  std::vector<InputFrame> f;
  for (InputFrame next; source->Next(&next);) f.push_back(next);
  ASSERT_EQ(f.size(), 4u);
  for (const InputFrame& x : f) {
    ASSERT_FALSE(x.image.empty()) << x.source << ": " << x.error;
    EXPECT_EQ(x.image.type(), CV_8UC3) << x.source;
  }
  EXPECT_EQ(f[0].image.at<cv::Vec3b>(0, 0), cv::Vec3b(125, 125, 125));  // 2000 of 4095
  EXPECT_EQ(f[0].image.at<cv::Vec3b>(0, 1)[0], 249);                    // 4000 of 4095
  EXPECT_EQ(f[1].image.at<cv::Vec3b>(0, 0), cv::Vec3b(255, 62, 19));    // one scale for the camera
  EXPECT_EQ(f[2].image.at<cv::Vec3b>(0, 0)[0], 233);                    // 60000 of 65535
  EXPECT_EQ(f[3].image.at<cv::Vec3b>(0, 0), cv::Vec3b(7, 8, 9));        // 8-bit frames as they are
}

TEST(FrameSource, TheDepthOnlyRisesWithinASource) {
  std::atomic<int> bits{8};
  const cv::Mat twelve(4, 4, CV_16UC1, cv::Scalar(4095)), dark(4, 4, CV_16UC1, cv::Scalar(1000));
  EXPECT_EQ(ToEightBit(twelve, &bits).at<uint8_t>(0, 0), 255);
  EXPECT_EQ(bits.load(), 12);
  // A darker frame after it keeps the 12-bit scale: not brightened as if it were 10-bit.
  EXPECT_EQ(ToEightBit(dark, &bits).at<uint8_t>(0, 0), 62);
  EXPECT_EQ(ToEightBit(cv::Mat(4, 4, CV_32FC1, cv::Scalar(0.5)), &bits).at<uint8_t>(0, 0), 128);
}

}  // namespace
}  // namespace rolamos
