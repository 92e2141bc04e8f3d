#include "util/codecs.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include <gtest/gtest.h>

#include "test_support.h"

namespace rolamos {
namespace {

// The tests link the library whole: OpenCV's codecs are registered before main, and each call is
// OpenCV's own.
TEST(Codecs, LinkedInProgramsUseOpenCvsOwn) {
  ASSERT_TRUE(CodecsLinkedIn());
  test::ScratchDir dir;
  const cv::Mat image = test::MakeImage(64, 48, 3, 8);
  std::vector<unsigned char> png;
  ASSERT_TRUE(EncodeImage(".png", image, &png));
  std::vector<unsigned char> theirs;
  cv::imencode(".png", image, theirs);
  EXPECT_EQ(png, theirs);
  cv::imwrite(dir / "a.png", image);
  EXPECT_EQ(cv::norm(ReadImageFile(dir / "a.png", cv::IMREAD_COLOR), image, cv::NORM_INF), 0);
  EXPECT_TRUE(ReadImageFile(dir / "missing.png", cv::IMREAD_COLOR).empty());
  EXPECT_FALSE(EncodeImage(".not-a-format", image, &png));
}

TEST(Codecs, VideoReadsEveryFrameAndNothingElse) {
  test::ScratchDir dir;
  {
    cv::VideoWriter out(dir / "v.avi", cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10, cv::Size(64, 48));
    ASSERT_TRUE(out.isOpened());
    for (int i = 0; i < 5; ++i) out.write(test::MakeImage(64, 48, 3, 8, i));
  }
  std::unique_ptr<VideoReader> video = OpenVideo(dir / "v.avi");
  ASSERT_TRUE(video);
  EXPECT_EQ(video->FrameCount(), 5);
  cv::Mat frame;
  int frames = 0;
  while (video->Read(&frame)) {
    EXPECT_EQ(frame.size(), cv::Size(64, 48));
    ++frames;
  }
  EXPECT_EQ(frames, 5);
  EXPECT_FALSE(OpenVideo(dir / "missing.avi"));
}

}  // namespace
}  // namespace rolamos
