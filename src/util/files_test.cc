#include "util/files.h"

#include <algorithm>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace rolamos {
namespace {

TEST(NaturalLess, NumbersByTheirValueTheRestAsBytes) {
  EXPECT_TRUE(NaturalLess("frame9.jpg", "frame10.jpg"));
  EXPECT_FALSE(NaturalLess("frame10.jpg", "frame9.jpg"));
  EXPECT_TRUE(NaturalLess("frame_00009.jpg", "frame_00010.jpg"));  // padded names: as before
  EXPECT_TRUE(NaturalLess("dive2/f100.png", "dive10/f1.png"));
  EXPECT_TRUE(NaturalLess("a.jpg", "b.jpg"));
  EXPECT_TRUE(NaturalLess("frame", "frame1"));                    // a prefix first
  EXPECT_FALSE(NaturalLess("x", "x"));
  // Equal but for leading zeros: byte order, so that the order is total.
  EXPECT_NE(NaturalLess("f01", "f1"), NaturalLess("f1", "f01"));
  // As ffmpeg's frame%d.jpg names them, shuffled: back in the camera's order.
  std::vector<std::string> names, expected;
  for (int i = 1; i <= 120; ++i) expected.push_back("frame" + std::to_string(i) + ".jpg");
  names = expected;
  std::sort(names.begin(), names.end());  // 1, 10, 100, 101, ...
  ASSERT_NE(names, expected);
  std::sort(names.begin(), names.end(), NaturalLess);
  EXPECT_EQ(names, expected);
}

}  // namespace
}  // namespace rolamos
