// Resampling that treats alpha as coverage: colours are premultiplied before interpolation and
// divided back after, so data never darkens where it meets "no data".
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// dst(i, j) = src(M * (j, i, 1)) with M a 2x3 dst->src affine map (CV_64F). Pixels mapped
// outside src are repeated from the border (opaque images) or transparent (with alpha).
// prefilter_sigma > 0 blurs src first (anti-aliasing when shrinking).
cv::Mat WarpRespectingAlpha(const cv::Mat& src, const cv::Mat& dst_to_src, cv::Size size,
                            bool has_alpha, double prefilter_sigma = 0.0);

}  // namespace rolamos
