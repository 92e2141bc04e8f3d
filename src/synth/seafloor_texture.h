// A procedural seafloor: sand with ripples, pebbles and rocky outcrops, deterministic in
// absolute pixel coordinates, so any window of an arbitrarily large image can be rendered on its
// own (bands of a gigapixel test image, frames of a synthetic survey) and windows always agree.
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

namespace rolamos {

struct SeafloorTextureOptions {
  uint32_t seed = 1;
  double feature_scale = 1.0;  // > 1 makes every structure larger
};

// Pixels [x, x + cols) x [y, y + rows) as 8-bit BGR.
cv::Mat RenderSeafloor(long long x, long long y, int cols, int rows,
                       const SeafloorTextureOptions& options = {});

}  // namespace rolamos
