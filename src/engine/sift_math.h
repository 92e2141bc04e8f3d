// Vector arithmetic SIFT's keypoints and descriptors share (AVX-512; callers check the CPU).
#pragma once

#include <cfloat>
#include <algorithm>
#include <cmath>
#include <vector>

#include <immintrin.h>

#include <opencv2/core.hpp>

namespace rolamos {

// OpenCV's fastAtan2 polynomial (the same operations: its orientations, to the bit), degrees in
// [0, 360), sixteen at a time.
__attribute__((target("avx512f,fma"))) inline __m512 Atan2Degrees(__m512 y, __m512 x) {
  const __m512 ax = _mm512_abs_ps(x), ay = _mm512_abs_ps(y);
  const __m512 c =
      _mm512_div_ps(_mm512_min_ps(ax, ay), _mm512_add_ps(_mm512_max_ps(ax, ay), _mm512_set1_ps(float(DBL_EPSILON))));
  const __m512 cc = _mm512_mul_ps(c, c);
  const float k = float(180 / CV_PI);
  __m512 a = _mm512_fmadd_ps(cc, _mm512_set1_ps(-0.04432655554792128f * k), _mm512_set1_ps(0.1555786518463281f * k));
  a = _mm512_fmadd_ps(a, cc, _mm512_set1_ps(-0.3258083974640975f * k));
  a = _mm512_mul_ps(_mm512_fmadd_ps(a, cc, _mm512_set1_ps(0.9997878412794807f * k)), c);
  a = _mm512_mask_sub_ps(a, _mm512_cmp_ps_mask(ax, ay, _CMP_LT_OQ), _mm512_set1_ps(90.f), a);
  const __m512 zero = _mm512_setzero_ps();
  a = _mm512_mask_sub_ps(a, _mm512_cmp_ps_mask(x, zero, _CMP_LT_OQ), _mm512_set1_ps(180.f), a);
  a = _mm512_mask_sub_ps(a, _mm512_cmp_ps_mask(y, zero, _CMP_LT_OQ), _mm512_set1_ps(360.f), a);
  return a;
}

// Asks for columns [first, last] of row y of `img` (float) to be brought into cache: a keypoint's
// window walks down rows a frame's pitch apart, which the hardware does not foresee, and its
// loads waited on memory for ~40 % of a descriptor's time in the engine.
inline void PrefetchRow(const cv::Mat& img, int y, int first, int last) {
  if (y < 0 || y >= img.rows) return;
  first = std::max(first, 0);
  last = std::min(last, img.cols - 1);
  const float* row = img.ptr<float>(y);
  for (int x = first; x <= last; x += 16) _mm_prefetch(reinterpret_cast<const char*>(row + x), _MM_HINT_T0);
  _mm_prefetch(reinterpret_cast<const char*>(row + last), _MM_HINT_T0);
}

// Rows ahead of the one a window's loop is on that PrefetchRow asks for.
inline constexpr int kPrefetchRows = 4;

// The gradients SIFT's orientations and descriptors take at columns x .. x + 15 of row y (the
// lanes in `valid`; the others 0): dx = I(y, x + 1) - I(y, x - 1), dy = I(y - 1, x) - I(y + 1, x).
__attribute__((target("avx512f"))) inline void Gradients(const cv::Mat& img, int y, int x, __mmask16 valid, __m512* dx,
                                                         __m512* dy) {
  const float* here = img.ptr<float>(y);
  *dx = _mm512_sub_ps(_mm512_maskz_loadu_ps(valid, here + x + 1), _mm512_maskz_loadu_ps(valid, here + x - 1));
  *dy = _mm512_sub_ps(_mm512_maskz_loadu_ps(valid, img.ptr<float>(y - 1) + x),
                      _mm512_maskz_loadu_ps(valid, img.ptr<float>(y + 1) + x));
}

// exp(scale j^2) for j in [-radius, radius] at table[j + radius], then 16 zeros (a vector read
// from the last column stays inside): a window's Gaussian weight is the product of its row's and
// its column's.
inline void GaussianFactors(int radius, float scale, std::vector<float>* table) {
  table->assign(static_cast<size_t>(2 * radius + 1 + 16), 0.f);
  for (int j = -radius; j <= radius; ++j) (*table)[size_t(j + radius)] = std::exp(float(j * j) * scale);
}

}  // namespace rolamos
