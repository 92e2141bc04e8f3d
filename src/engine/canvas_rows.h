// The patch canvas's row kernels (patch_canvas.h), where its per-pixel loops cost the most: a
// frame's colour correction into 16 bits and its interleaving with the feather code, the working
// canvas's accumulation with its 2 x 2 means, and the rendering of the sums. Each has a scalar
// rule and a vector form (AVX2 or AVX-512, where the CPU has it) that gives the same values, bit
// for bit: the same products and sums in the same order (patch_canvas_test.cc).
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// `n` 8-bit values of a row times the colour correction (one factor per value, or none: `c`
// null) and `s`, rounded and saturated to 16 bits.
void CorrectRow(const uchar* p, const float* c, float s, int n, ushort* out);

// Pixels [0, n): corrected values (B, G, R, B, ...) and codes into (B, G, R, code) words.
void InterleaveDeepRow(const ushort* row, const uchar* code, int n, cv::Vec4w* out);

// The working canvas's accumulation of one row: pixels [0, n) of `px` (BGRW) into the sums from
// column `col` of a block, and into the row of its 2 x 2 means (`small`, `small_w`, indexed by
// the block's column / 2): weight[code] x colour and weight[code], each a quarter into its cell;
// code 0 adds nothing.
void AddReducedRow(const cv::Vec4b* px, int n, int col, const float* weight, cv::Vec3f* acc, float* wsum,
                   cv::Vec3f* small, float* small_w);

// Pixels [0, n) of a rendered row: where the weight passes kAlphaCut, the sums over the weight
// (times 1 / weight, rounded and saturated as cv::saturate_cast does) and alpha 255; elsewhere
// all zero.
void RenderSumsRow(const cv::Vec3f* sum, const float* weight, int n, cv::Vec4b* out);

}  // namespace rolamos
