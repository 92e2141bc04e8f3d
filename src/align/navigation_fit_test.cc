#include "align/navigation_fit.h"

#include <cmath>

#include <gtest/gtest.h>

#include "util/homography.h"

namespace rolamos {
namespace {

// A lane and the start of a turn, seen in image pixels (y down) and on a map (north up): a
// mirror image. Twenty of the twenty-five points are on one line, where a turn fits as well as
// the mirror; the five in the turn decide (the live view's georeference chose the turn).
TEST(NavigationFit, AMostlyStraightTrackIsFittedAsTheMirrorItIs) {
  std::vector<cv::Point2d> image, map;
  for (int i = 0; i < 25; ++i) {
    const double along = 72.0 * std::min(i, 19) + (i > 19 ? 30.0 * (i - 19) : 0.0);
    const double across = i > 19 ? -25.0 * (i - 19) * (i - 19) / 4.0 : 0.0;
    image.emplace_back(240 + across, 180 + along);
    // Map metres: 0.01 m a pixel, image y -> east, image x -> north (a mirror, not a turn).
    map.emplace_back(500000 + 0.01 * (180 + along), 5200000 + 0.01 * (240 + across));
  }
  const auto M = FitSimilarity(image, map);
  ASSERT_TRUE(M.has_value());
  for (size_t i = 0; i < image.size(); ++i)
    EXPECT_LT(cv::norm(ApplyHomography(*M, image[i]) - map[i]), 1e-3) << "point " << i;
}

}  // namespace
}  // namespace rolamos
