// 2x2 area averaging for pyramid levels. With an alpha channel, colours are weighted by alpha so
// that transparent pixels never darken data at its borders, and alpha itself is averaged.
// Odd sizes: the last column/row is averaged with itself (output is ceil(w/2) x ceil(h/2)).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

cv::Mat Downsample2x(const cv::Mat& src, bool has_alpha);

}  // namespace rolamos
