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

}  // namespace
}  // namespace rolamos
