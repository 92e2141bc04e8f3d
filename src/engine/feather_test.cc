#include "engine/feather.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// The 8-bit code must give back every weight the engine uses within one code step (3.7 %),
// never lose the floor (sigma 0.01 frames would vanish) and fade to zero only on the outer ring.
TEST(FeatherCode, KeepsEveryWeightWithinOneStepAndZeroesOnlyTheOuterRing) {
  for (double sigma : {0.2, 0.1, 0.01, 0.0}) {
    const cv::Size size(321, 207);
    const cv::Mat w = FeatherWeights(size, sigma);
    const FeatherCode code(w);
    ASSERT_EQ(code.code.size(), size);
    for (int y = 0; y < size.height; ++y) {
      for (int x = 0; x < size.width; ++x) {
        const uchar c = code.code.at<uchar>(y, x);
        const bool edge = x == 0 || y == 0 || x == size.width - 1 || y == size.height - 1;
        if (edge) {
          ASSERT_EQ(c, 0) << "sigma " << sigma << " at " << x << "," << y;
          continue;
        }
        ASSERT_GE(c, 1) << "sigma " << sigma << " at " << x << "," << y;
        const float back = code.weight[c], truth = w.at<float>(y, x);
        ASSERT_NEAR(back / truth, 1.0, 0.02) << "sigma " << sigma << " at " << x << "," << y;
      }
    }
  }
  const FeatherCode code(FeatherWeights({10, 10}, 0.2));
  EXPECT_EQ(code.weight[0], 0.f);
  EXPECT_FLOAT_EQ(code.weight[255], 1.f);
  EXPECT_NEAR(code.weight[1], kFeatherFloor, 1e-9);
}

}  // namespace
}  // namespace rolamos
