#include "raster/downsample.h"

#include <immintrin.h>

#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

// floor(n / d) for the sums of AlphaWeighted: 8-bit ones stay below 2^24, exact in float, and
// n / d lies either on an integer or at least 1 / d (>= 1 / 1020) from one, far more than the
// float quotient's rounding: it truncates to the integer quotient without a 64-bit division
// (checked for every n and d the sums can take).
inline uint64_t Quotient(uint64_t n, uint64_t d, uint8_t) { return static_cast<uint64_t>(float(n) / float(d)); }
inline uint64_t Quotient(uint64_t n, uint64_t d, uint16_t) { return n / d; }

// 8-bit BGRA, four output pixels at a time (one per 128-bit lane, a channel per 32-bit element),
// the same sums and quotients as the pixel loop. Returns the columns done.
__attribute__((target("avx512f,avx2"))) int AlphaWeightedRowAvx512(const uint8_t* r0, const uint8_t* r1,
                                                                    uint8_t* out, int cols) {
  // Each 8-pixel load's even pixels in its low half, odd ones in its high half.
  const __m256i split = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
  const __m512i one = _mm512_set1_epi32(1), two = _mm512_set1_epi32(2);
  const __mmask16 alpha = 0x8888;  // each pixel's fourth channel
  int x = 0;
  for (; x + 4 <= cols; x += 4) {
    const __m256i a = _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(r0 + 8 * x)), split);
    const __m256i b = _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(r1 + 8 * x)), split);
    const __m512i p[4] = {_mm512_cvtepu8_epi32(_mm256_castsi256_si128(a)), _mm512_cvtepu8_epi32(_mm256_extracti128_si256(a, 1)),
                          _mm512_cvtepu8_epi32(_mm256_castsi256_si128(b)), _mm512_cvtepu8_epi32(_mm256_extracti128_si256(b, 1))};
    __m512i sum = _mm512_setzero_si512(), weight = _mm512_setzero_si512();
    for (const __m512i& q : p) {
      const __m512i w = _mm512_shuffle_epi32(q, _MM_PERM_DDDD);
      sum = _mm512_add_epi32(sum, _mm512_mullo_epi32(q, w));
      weight = _mm512_add_epi32(weight, w);
    }
    const __m512 n = _mm512_cvtepi32_ps(_mm512_add_epi32(sum, _mm512_srli_epi32(weight, 1)));
    __m512i v = _mm512_cvttps_epi32(_mm512_div_ps(n, _mm512_cvtepi32_ps(_mm512_max_epi32(weight, one))));
    v = _mm512_mask_mov_epi32(v, alpha, _mm512_srli_epi32(_mm512_add_epi32(weight, two), 2));
    v = _mm512_maskz_mov_epi32(_mm512_cmpneq_epi32_mask(weight, _mm512_setzero_si512()), v);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 4 * x), _mm512_cvtepi32_epi8(v));
  }
  return x;
}

template <typename T>
void AlphaWeighted(const cv::Mat& src, cv::Mat& dst) {
  const int cn = src.channels();
  const int ac = cn - 1;  // alpha is last
  const bool vector = CpuHasAvx512() && sizeof(T) == 1 && cn == 4;
  cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const T* r0 = src.ptr<T>(2 * y);
      const T* r1 = src.ptr<T>(2 * y + 1);
      T* out = dst.ptr<T>(y);
      int x = 0;
      if constexpr (sizeof(T) == 1)
        if (vector) x = AlphaWeightedRowAvx512(r0, r1, out, dst.cols);
      for (; x < dst.cols; ++x) {
        const T* p[4] = {r0 + 2 * x * cn, r0 + (2 * x + 1) * cn, r1 + 2 * x * cn,
                         r1 + (2 * x + 1) * cn};
        const uint64_t a = uint64_t(p[0][ac]) + p[1][ac] + p[2][ac] + p[3][ac];
        T* o = out + x * cn;
        if (a == 0) {
          for (int c = 0; c < cn; ++c) o[c] = 0;
          continue;
        }
        for (int c = 0; c < ac; ++c) {
          const uint64_t s = uint64_t(p[0][c]) * p[0][ac] + uint64_t(p[1][c]) * p[1][ac] +
                             uint64_t(p[2][c]) * p[2][ac] + uint64_t(p[3][c]) * p[3][ac];
          o[c] = static_cast<T>(Quotient(s + a / 2, a, T()));
        }
        o[ac] = static_cast<T>((a + 2) / 4);
      }
    }
  });
}

}  // namespace

cv::Mat Downsample2x(const cv::Mat& src, bool has_alpha) {
  CV_Assert(!src.empty());
  cv::Mat even = src;
  const int pad_x = src.cols & 1, pad_y = src.rows & 1;
  if (pad_x || pad_y) cv::copyMakeBorder(src, even, 0, pad_y, 0, pad_x, cv::BORDER_REPLICATE | cv::BORDER_ISOLATED);  // not the rows past a view
  cv::Mat dst(even.rows / 2, even.cols / 2, src.type());
  if (!has_alpha) {
    // Exact halving takes OpenCV's fast 2x2 box path.
    cv::resize(even, dst, dst.size(), 0, 0, cv::INTER_AREA);
  } else if (src.depth() == CV_8U) {
    AlphaWeighted<uint8_t>(even, dst);
  } else {
    AlphaWeighted<uint16_t>(even, dst);
  }
  return dst;
}

}  // namespace rolamos
