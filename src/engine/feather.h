// Stage 5: blending weights. A 2-D Gaussian centred on the frame, sigma given as a fraction of
// the frame's width and height (the paper compares 0.2, 0.1 and 0.01); 0 means plain averaging.
// A small floor keeps every pixel of a frame counted, so even sigma 0.01 covers the frame.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

inline constexpr float kFeatherFloor = 1e-4f;
// Accumulated weight below which a canvas pixel counts as "no data".
inline constexpr float kAlphaCut = 0.5f * kFeatherFloor;

cv::Mat FeatherWeights(cv::Size frame, double sigma_fraction);

}  // namespace rolamos
