// Stage 5: blending weights. A 2-D Gaussian centred on the frame, sigma given as a fraction of
// the frame's width and height (the paper compares 0.2, 0.1 and 0.01); 0 means plain averaging.
// A small floor keeps every pixel of a frame counted, so even sigma 0.01 covers the frame.
#pragma once

#include <array>

#include <opencv2/core.hpp>

namespace rolamos {

inline constexpr float kFeatherFloor = 1e-4f;
// Accumulated weight below which a canvas pixel counts as "no data".
inline constexpr float kAlphaCut = 0.5f * kFeatherFloor;

cv::Mat FeatherWeights(cv::Size frame, double sigma_fraction);

// The weights as one 8-bit plane, so they travel in a frame's fourth channel and one 4-channel
// warp moves colour and weight together (a separate float warp costs as much again). The code
// is logarithmic: 255 is weight 1, 1 is kFeatherFloor, steps of 3.7 %; 0 is no weight. The
// frame's outermost pixels get 0, so a warp that repeats edge pixels fades the weight to nothing
// just outside the frame while the colours there stay the frame's own.
struct FeatherCode {
  explicit FeatherCode(const cv::Mat& weights);
  // The code of a rectangle of the frame (shared pixels), for blending that part of a frame.
  FeatherCode Part(const cv::Rect& r) const;
  cv::Mat code;                 // CV_8U, the frame's size
  std::array<float, 256> weight;  // code -> weight

 private:
  FeatherCode() = default;
};

}  // namespace rolamos
