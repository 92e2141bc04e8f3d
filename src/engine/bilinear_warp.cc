#include "engine/bilinear_warp.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>

#include <immintrin.h>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "util/cpu_features.h"

namespace rolamos {
namespace {

// Destination pixels whose source positions are found at once.
constexpr int kRun = 8;
// Source positions are found in double and rounded to 1/256 px (OpenCV: 1/32): a band of a frame
// warped with its offset folded into the placement then samples exactly what the whole frame
// does, so a patch written band by band is the patch rendered whole.
constexpr int kSubBits = 8;
constexpr double kSub = 1 << kSubBits;
constexpr float kInvSub = 1.0f / (1 << kSubBits);

struct Limits {
  double lo_x, hi_x, lo_y, hi_y;
  explicit Limits(const cv::Mat& src)
      : lo_x(-2 * kSub), hi_x((src.cols + 1) * kSub), lo_y(-2 * kSub), hi_y((src.rows + 1) * kSub) {}
};

// One pixel by the book: taps clamped into the image (edge pixels repeated).
template <typename T>
void InterpolateClamped(const cv::Mat& src, int qx, int qy, float out[4]) {
  const int x0 = qx >> kSubBits, y0 = qy >> kSubBits;
  const float ax = (qx & ((1 << kSubBits) - 1)) * kInvSub, ay = (qy & ((1 << kSubBits) - 1)) * kInvSub;
  const int xa = std::clamp(x0, 0, src.cols - 1), xb = std::clamp(x0 + 1, 0, src.cols - 1);
  const int ya = std::clamp(y0, 0, src.rows - 1), yb = std::clamp(y0 + 1, 0, src.rows - 1);
  const T* r0 = src.ptr<T>(ya);
  const T* r1 = src.ptr<T>(yb);
  for (int c = 0; c < 4; ++c) {
    const float top = r0[4 * xa + c] + ax * (float(r0[4 * xb + c]) - float(r0[4 * xa + c]));
    const float bottom = r1[4 * xa + c] + ax * (float(r1[4 * xb + c]) - float(r1[4 * xa + c]));
    out[c] = top + ay * (bottom - top);
  }
}

// A pixel's four channels (the taps at `a` and `b` of a row) as eight floats: a's, then b's.
__attribute__((target("avx2"))) inline __m256 Load2(const uint8_t* a, const uint8_t* b) {
  int32_t wa, wb;
  std::memcpy(&wa, a, 4);
  std::memcpy(&wb, b, 4);
  return _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_setr_epi32(wa, wb, 0, 0)));
}
__attribute__((target("avx2"))) inline __m256 Load2(const uint16_t* a, const uint16_t* b) {
  const __m128i lo = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(a));
  const __m128i hi = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(b));
  return _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(_mm_unpacklo_epi64(lo, hi)));
}
// Two neighbouring pixels' four channels (8 values from `a`) as eight floats.
__attribute__((target("avx2"))) inline __m256 LoadPair(const uint8_t* a) {
  return _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(a))));
}
__attribute__((target("avx2"))) inline __m256 LoadPair(const uint16_t* a) {
  return _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(a))));
}
// Four positions along one axis: (a x + b) / w in 1/256 px, clamped (max(v, lo) is lo when v
// is not a number), rounded.
__attribute__((target("avx2,fma"))) inline __m128i Axis4(__m256d a, __m256d b, __m256d scale, __m256d xs,
                                                         double lo, double hi) {
  __m256d v = _mm256_mul_pd(_mm256_fmadd_pd(a, xs, b), scale);
  v = _mm256_min_pd(_mm256_max_pd(v, _mm256_set1_pd(lo)), _mm256_set1_pd(hi));
  return _mm256_cvtpd_epi32(_mm256_round_pd(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
}

__attribute__((target("avx2"))) inline __m256i Clamp(__m256i v, __m256i hi) {
  return _mm256_min_epi32(_mm256_max_epi32(v, _mm256_setzero_si256()), hi);
}

// A run of pixels' taps: element offsets of the four neighbours (edge pixels repeated) and the
// fractions between them.
struct Taps {
  alignas(32) int left[kRun], right[kRun], top[kRun], bottom[kRun];
  alignas(32) float ax[kRun], ay[kRun];
};

__attribute__((target("avx2,fma"))) void TapsAvx2(const cv::Matx33d& m, int x, int y, const Limits& lim,
                                                  int cols, int rows, int step, Taps* t) {
  const __m256d ax = _mm256_set1_pd(m(0, 0)), bx = _mm256_set1_pd(m(0, 1) * y + m(0, 2));
  const __m256d ay = _mm256_set1_pd(m(1, 0)), by = _mm256_set1_pd(m(1, 1) * y + m(1, 2));
  const __m256d aw = _mm256_set1_pd(m(2, 0)), bw = _mm256_set1_pd(m(2, 1) * y + m(2, 2));
  __m128i q[2][2];
  for (int half = 0; half < 2; ++half) {
    const __m256d xs = _mm256_add_pd(_mm256_set1_pd(x + 4 * half), _mm256_setr_pd(0, 1, 2, 3));
    const __m256d scale = _mm256_div_pd(_mm256_set1_pd(kSub), _mm256_fmadd_pd(aw, xs, bw));
    q[0][half] = Axis4(ax, bx, scale, xs, lim.lo_x, lim.hi_x);
    q[1][half] = Axis4(ay, by, scale, xs, lim.lo_y, lim.hi_y);
  }
  const __m256i qx = _mm256_set_m128i(q[0][1], q[0][0]), qy = _mm256_set_m128i(q[1][1], q[1][0]);
  const __m256i mask = _mm256_set1_epi32((1 << kSubBits) - 1);
  const __m256 inv = _mm256_set1_ps(kInvSub);
  _mm256_store_ps(t->ax, _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(qx, mask)), inv));
  _mm256_store_ps(t->ay, _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(qy, mask)), inv));
  const __m256i x0 = _mm256_srai_epi32(qx, kSubBits), y0 = _mm256_srai_epi32(qy, kSubBits);
  const __m256i one = _mm256_set1_epi32(1), last_x = _mm256_set1_epi32(cols - 1), last_y = _mm256_set1_epi32(rows - 1);
  const __m256i four = _mm256_set1_epi32(4), st = _mm256_set1_epi32(step);
  _mm256_store_si256(reinterpret_cast<__m256i*>(t->left), _mm256_mullo_epi32(Clamp(x0, last_x), four));
  _mm256_store_si256(reinterpret_cast<__m256i*>(t->right), _mm256_mullo_epi32(Clamp(_mm256_add_epi32(x0, one), last_x), four));
  _mm256_store_si256(reinterpret_cast<__m256i*>(t->top), _mm256_mullo_epi32(Clamp(y0, last_y), st));
  _mm256_store_si256(reinterpret_cast<__m256i*>(t->bottom), _mm256_mullo_epi32(Clamp(_mm256_add_epi32(y0, one), last_y), st));
}

// Pixels begin .. end - 1 of output row y, handed to `sink` a run at a time, each pixel as four
// floats (B, G, R, code).
template <typename T, typename Sink>
__attribute__((target("avx2,fma"))) void RowAvx2(const cv::Mat& src, const cv::Matx33d& m, int y, int begin,
                                                 int end, Sink& sink) {
  const Limits lim(src);
  const int step = static_cast<int>(src.step / sizeof(T));
  const T* base = src.ptr<T>(0);
  Taps t;
  alignas(32) float values[kRun][4];
  for (int x = begin; x < end; x += kRun) {
    TapsAvx2(m, x, y, lim, src.cols, src.rows, step, &t);
    const int n = std::min(kRun, end - x);
    for (int i = 0; i < n; ++i) {
      const T* r0 = base + t.top[i];
      const T* r1 = base + t.bottom[i];
      __m256 upper, lower;
      if (t.right[i] == t.left[i] + 4) {  // the two taps side by side: one load a row
        upper = LoadPair(r0 + t.left[i]);
        lower = LoadPair(r1 + t.left[i]);
      } else {
        upper = Load2(r0 + t.left[i], r0 + t.right[i]);
        lower = Load2(r1 + t.left[i], r1 + t.right[i]);
      }
      const __m256 v = _mm256_fmadd_ps(_mm256_sub_ps(lower, upper), _mm256_set1_ps(t.ay[i]), upper);
      const __m128 left = _mm256_castps256_ps128(v), right = _mm256_extractf128_ps(v, 1);
      _mm_store_ps(values[i], _mm_fmadd_ps(_mm_sub_ps(right, left), _mm_set1_ps(t.ax[i]), left));
    }
    sink.Run(x - begin, values, n);
  }
}

int Quantised(double v, double lo, double hi) {
  return static_cast<int>(std::lround(std::isnan(v) ? lo : std::clamp(v, lo, hi)));
}

template <typename T, typename Sink>
void RowScalar(const cv::Mat& src, const cv::Matx33d& m, int y, int begin, int end, Sink& sink) {
  const Limits lim(src);
  for (int x = begin; x < end; ++x) {
    const double scale = kSub / (m(2, 0) * x + m(2, 1) * y + m(2, 2));
    const int qx = Quantised((m(0, 0) * x + m(0, 1) * y + m(0, 2)) * scale, lim.lo_x, lim.hi_x);
    const int qy = Quantised((m(1, 0) * x + m(1, 1) * y + m(1, 2)) * scale, lim.lo_y, lim.hi_y);
    float v[4];
    InterpolateClamped<T>(src, qx, qy, v);
    sink.Scalar(x - begin, v);
  }
}

template <typename T, typename Sink>
void Row(const cv::Mat& src, const cv::Matx33d& dst_to_src, int y, int begin, int end, Sink& sink) {
  if (CpuHasAvx2Fma())
    RowAvx2<T>(src, dst_to_src, y, begin, end, sink);
  else
    RowScalar<T>(src, dst_to_src, y, begin, end, sink);
}

// Adds each pixel to a canvas row: weight[code] x colour x unit to the sums, weight[code] to the
// weights; code 0 (beyond the frame) adds nothing.
struct AccumulateSink {
  cv::Vec3f* sum;
  float* weight_sum;
  const float* weight;
  float unit;
  bool wide = CpuHasAvx512();
  // A run of pixels x .. x + n - 1: a whole run eight at a time (the same products and sums as
  // Scalar's, lane by lane; a pixel of code 0 adds zeros, which leaves its sums as they were).
  // Pixel by pixel, the lookup of each code's weight waited on the code's rounding, and the sums
  // on the lookup: half the warp's time.
  __attribute__((target("avx512f,avx2,fma"))) void Run(int x, const float (*v)[4], int n) {
    if (n < kRun || !wide) {
      for (int i = 0; i < n; ++i) Scalar(x + i, v[i]);
      return;
    }
    __m128 p[8];
    for (int i = 0; i < 8; ++i) p[i] = _mm_load_ps(v[i]);
    _MM_TRANSPOSE4_PS(p[0], p[1], p[2], p[3]);
    _MM_TRANSPOSE4_PS(p[4], p[5], p[6], p[7]);
    const __m256 b = _mm256_set_m128(p[4], p[0]), g = _mm256_set_m128(p[5], p[1]), r = _mm256_set_m128(p[6], p[2]);
    const __m256 c = _mm256_set_m128(p[7], p[3]);
    const __m256i code = _mm256_min_epi32(_mm256_cvtps_epi32(c), _mm256_set1_epi32(255));
    const __m256i used = _mm256_cmpgt_epi32(code, _mm256_setzero_si256());
    const __m256 a = _mm256_mask_i32gather_ps(_mm256_setzero_ps(), weight, _mm256_and_si256(code, used),
                                              _mm256_castsi256_ps(used), 4);
    const __m256 k = _mm256_mul_ps(a, _mm256_set1_ps(unit));
    // B, G, R of the eight pixels interleaved as the canvas holds them: 16 floats, then 8.
    const __m512 bg = _mm512_castpd_ps(_mm512_insertf64x4(_mm512_castpd256_pd512(_mm256_castps_pd(_mm256_mul_ps(b, k))),
                                                          _mm256_castps_pd(_mm256_mul_ps(g, k)), 1));
    const __m512 rr = _mm512_castps256_ps512(_mm256_mul_ps(r, k));
    const __m512i first = _mm512_setr_epi32(0, 8, 16, 1, 9, 17, 2, 10, 18, 3, 11, 19, 4, 12, 20, 5);
    const __m512i second = _mm512_setr_epi32(13, 21, 6, 14, 22, 7, 15, 23, 0, 0, 0, 0, 0, 0, 0, 0);
    float* s = sum[x].val;
    _mm512_storeu_ps(s, _mm512_add_ps(_mm512_loadu_ps(s), _mm512_permutex2var_ps(bg, first, rr)));
    _mm256_storeu_ps(s + 16, _mm256_add_ps(_mm256_loadu_ps(s + 16),
                                           _mm512_castps512_ps256(_mm512_permutex2var_ps(bg, second, rr))));
    _mm256_storeu_ps(weight_sum + x, _mm256_add_ps(_mm256_loadu_ps(weight_sum + x), a));
  }
  void Scalar(int x, const float v[4]) {
    const int code = std::min(cvRound(v[3]), 255);
    if (code <= 0) return;
    const float a = weight[code];
    const float k = a * unit;
    sum[x] += cv::Vec3f(v[0] * k, v[1] * k, v[2] * k);
    weight_sum[x] += a;
  }
};

// Sixteen pixels' positions as TapsAvx2 finds them (double, the same operations in the same
// order), then their taps gathered and interpolated channel by channel with the same fused
// operations as RowAvx2's, and added as AccumulateSink adds eight: the same sums to the bit.
// RowAvx2 took each pixel's taps one by one, half the full-resolution blend's time.
struct Taps16 {
  __m512i left, right, top, bottom;  // element offsets, edge pixels repeated
  __m512 ax, ay;
};

__attribute__((target("avx512f,fma"))) inline __m256i Axis8(__m512d a, __m512d b, __m512d scale, __m512d xs,
                                                            double lo, double hi) {
  __m512d v = _mm512_mul_pd(_mm512_fmadd_pd(a, xs, b), scale);
  v = _mm512_min_pd(_mm512_max_pd(v, _mm512_set1_pd(lo)), _mm512_set1_pd(hi));
  return _mm512_cvtpd_epi32(_mm512_roundscale_pd(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
}

__attribute__((target("avx512f"))) inline __m512i Clamp16(__m512i v, __m512i hi) {
  return _mm512_min_epi32(_mm512_max_epi32(v, _mm512_setzero_si512()), hi);
}

__attribute__((target("avx512f,fma"))) Taps16 TapsAvx512(const cv::Matx33d& m, int x, int y, const Limits& lim,
                                                         int cols, int rows, int step) {
  const __m512d ax = _mm512_set1_pd(m(0, 0)), bx = _mm512_set1_pd(m(0, 1) * y + m(0, 2));
  const __m512d ay = _mm512_set1_pd(m(1, 0)), by = _mm512_set1_pd(m(1, 1) * y + m(1, 2));
  const __m512d aw = _mm512_set1_pd(m(2, 0)), bw = _mm512_set1_pd(m(2, 1) * y + m(2, 2));
  __m256i q[2][2];
  for (int half = 0; half < 2; ++half) {
    const __m512d xs = _mm512_add_pd(_mm512_set1_pd(x + 8 * half), _mm512_setr_pd(0, 1, 2, 3, 4, 5, 6, 7));
    const __m512d scale = _mm512_div_pd(_mm512_set1_pd(kSub), _mm512_fmadd_pd(aw, xs, bw));
    q[0][half] = Axis8(ax, bx, scale, xs, lim.lo_x, lim.hi_x);
    q[1][half] = Axis8(ay, by, scale, xs, lim.lo_y, lim.hi_y);
  }
  const __m512i qx = _mm512_inserti64x4(_mm512_castsi256_si512(q[0][0]), q[0][1], 1);
  const __m512i qy = _mm512_inserti64x4(_mm512_castsi256_si512(q[1][0]), q[1][1], 1);
  const __m512i mask = _mm512_set1_epi32((1 << kSubBits) - 1);
  const __m512 inv = _mm512_set1_ps(kInvSub);
  Taps16 t;
  t.ax = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_and_si512(qx, mask)), inv);
  t.ay = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_and_si512(qy, mask)), inv);
  const __m512i x0 = _mm512_srai_epi32(qx, kSubBits), y0 = _mm512_srai_epi32(qy, kSubBits);
  const __m512i one = _mm512_set1_epi32(1), last_x = _mm512_set1_epi32(cols - 1), last_y = _mm512_set1_epi32(rows - 1);
  t.left = _mm512_slli_epi32(Clamp16(x0, last_x), 2);
  t.right = _mm512_slli_epi32(Clamp16(_mm512_add_epi32(x0, one), last_x), 2);
  t.top = _mm512_mullo_epi32(Clamp16(y0, last_y), _mm512_set1_epi32(step));
  t.bottom = _mm512_mullo_epi32(Clamp16(_mm512_add_epi32(y0, one), last_y), _mm512_set1_epi32(step));
  return t;
}

// One tap of sixteen pixels (element offsets `at`) as four planes of floats: B, G, R, code.
__attribute__((target("avx512f"))) inline void GatherTap(const uint8_t* base, __m512i at, __m512 (&c)[4]) {
  const __m512i px = _mm512_i32gather_epi32(at, base, 1);
  const __m512i byte = _mm512_set1_epi32(0xFF);
  for (int k = 0; k < 4; ++k) c[k] = _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(px, 8 * k), byte));
}
__attribute__((target("avx512f"))) inline void GatherTap(const uint16_t* base, __m512i at, __m512 (&c)[4]) {
  const __m512i lo = _mm512_i32gather_epi64(_mm512_castsi512_si256(at), base, 2);
  const __m512i hi = _mm512_i32gather_epi64(_mm512_extracti64x4_epi64(at, 1), base, 2);
  const __m256i word = _mm256_set1_epi32(0xFFFF);
  for (int k = 0; k < 4; ++k) {
    const __m256i a = _mm256_and_si256(_mm512_cvtepi64_epi32(_mm512_srli_epi64(lo, 16 * k)), word);
    const __m256i b = _mm256_and_si256(_mm512_cvtepi64_epi32(_mm512_srli_epi64(hi, 16 * k)), word);
    c[k] = _mm512_cvtepi32_ps(_mm512_inserti64x4(_mm512_castsi256_si512(a), b, 1));
  }
}

// Pixels [begin, end) of output row y added to the sink's row sixteen at a time; the last few by
// RowAvx2.
template <typename T>
__attribute__((target("avx512f,avx2,fma"))) void AccumulateRowAvx512(const cv::Mat& src, const cv::Matx33d& m, int y,
                                                                     int begin, int end, const AccumulateSink& sink) {
  const Limits lim(src);
  const int step = static_cast<int>(src.step / sizeof(T));
  const T* base = src.ptr<T>(0);
  // The run interleaved (B, G, R per pixel: 48 floats, three vectors): each vector's blues and
  // greens picked from the two, then its reds put in.
  const __m512i bg_index[3] = {_mm512_setr_epi32(0, 16, 0, 1, 17, 0, 2, 18, 0, 3, 19, 0, 4, 20, 0, 5),
                               _mm512_setr_epi32(21, 0, 6, 22, 0, 7, 23, 0, 8, 24, 0, 9, 25, 0, 10, 26),
                               _mm512_setr_epi32(0, 11, 27, 0, 12, 28, 0, 13, 29, 0, 14, 30, 0, 15, 31, 0)};
  const __mmask16 red_at[3] = {0x4924, 0x2492, 0x9249};
  const __m512i red_index[3] = {_mm512_setr_epi32(0, 0, 0, 0, 0, 1, 0, 0, 2, 0, 0, 3, 0, 0, 4, 0),
                                _mm512_setr_epi32(0, 5, 0, 0, 6, 0, 0, 7, 0, 0, 8, 0, 0, 9, 0, 0),
                                _mm512_setr_epi32(10, 0, 0, 11, 0, 0, 12, 0, 0, 13, 0, 0, 14, 0, 0, 15)};
  int x = begin;
  for (; x + 16 <= end; x += 16) {
    const Taps16 t = TapsAvx512(m, x, y, lim, src.cols, src.rows, step);
    __m512 tl[4], tr[4], bl[4], br[4];
    GatherTap(base, _mm512_add_epi32(t.top, t.left), tl);
    GatherTap(base, _mm512_add_epi32(t.top, t.right), tr);
    GatherTap(base, _mm512_add_epi32(t.bottom, t.left), bl);
    GatherTap(base, _mm512_add_epi32(t.bottom, t.right), br);
    __m512 v[4];
    for (int c = 0; c < 4; ++c) {
      const __m512 left = _mm512_fmadd_ps(_mm512_sub_ps(bl[c], tl[c]), t.ay, tl[c]);
      const __m512 right = _mm512_fmadd_ps(_mm512_sub_ps(br[c], tr[c]), t.ay, tr[c]);
      v[c] = _mm512_fmadd_ps(_mm512_sub_ps(right, left), t.ax, left);
    }
    const __m512i code = _mm512_min_epi32(_mm512_cvtps_epi32(v[3]), _mm512_set1_epi32(255));
    const __mmask16 used = _mm512_cmpgt_epi32_mask(code, _mm512_setzero_si512());
    const __m512 a = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), used, code, sink.weight, 4);
    const __m512 k = _mm512_mul_ps(a, _mm512_set1_ps(sink.unit));
    const __m512 b = _mm512_mul_ps(v[0], k), g = _mm512_mul_ps(v[1], k), r = _mm512_mul_ps(v[2], k);
    float* s = sink.sum[x - begin].val;
    for (int j = 0; j < 3; ++j) {
      const __m512 bg = _mm512_permutex2var_ps(b, bg_index[j], g);
      const __m512 out = _mm512_mask_permutexvar_ps(bg, red_at[j], red_index[j], r);
      _mm512_storeu_ps(s + 16 * j, _mm512_add_ps(_mm512_loadu_ps(s + 16 * j), out));
    }
    float* w = sink.weight_sum + (x - begin);
    _mm512_storeu_ps(w, _mm512_add_ps(_mm512_loadu_ps(w), a));
  }
  if (x < end) {
    AccumulateSink rest = sink;
    rest.sum += x - begin;
    rest.weight_sum += x - begin;
    RowAvx2<T>(src, m, y, x, end, rest);
  }
}

// One pixel of WarpInside at source position (fx, fy), as the vector path computes it.
void InsidePixel(const cv::Mat& src, float fx, float fy, uchar* out) {
  const float flx = std::floor(fx), fly = std::floor(fy);
  if (!(flx >= 0 && flx < src.cols - 1 && fly >= 0 && fly < src.rows - 1)) return;
  const int x0 = static_cast<int>(flx), y0 = static_cast<int>(fly);
  const float ax = fx - flx, ay = fy - fly;
  const uchar* r0 = src.ptr(y0) + 3 * x0;
  const uchar* r1 = src.ptr(y0 + 1) + 3 * x0;
  for (int c = 0; c < 3; ++c) {
    const float top = std::fma(ax, float(r0[3 + c]) - float(r0[c]), float(r0[c]));
    const float bottom = std::fma(ax, float(r1[3 + c]) - float(r1[c]), float(r1[c]));
    out[c] = cv::saturate_cast<uchar>(std::nearbyint(std::fma(ay, bottom - top, top)));
  }
}

// WarpInside's rows [y_begin, y_end), sixteen pixels at a time. The four taps of a pixel are
// gathered as 32-bit words (B, G, R and the next byte); the pixel whose last tap is the image's
// last pixel is done by InsidePixel, whose reads end inside the image.
__attribute__((target("avx512f"))) void WarpInsideRows(const cv::Mat& src, const cv::Matx33d& m, cv::Mat& dst,
                                                       int y_begin, int y_end) {
  const int step = static_cast<int>(src.step);
  const __m512 lanes = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i zero = _mm512_setzero_si512(), three = _mm512_set1_epi32(3), rows = _mm512_set1_epi32(step);
  const __m512i last_x = _mm512_set1_epi32(src.cols - 1), last_y = _mm512_set1_epi32(src.rows - 1);
  const __m512i corner_x = _mm512_set1_epi32(src.cols - 2), corner_y = _mm512_set1_epi32(src.rows - 2);
  const __m512i byte = _mm512_set1_epi32(0xFF);
  const __m512 m00 = _mm512_set1_ps(float(m(0, 0))), m10 = _mm512_set1_ps(float(m(1, 0))),
               m20 = _mm512_set1_ps(float(m(2, 0)));
  for (int y = y_begin; y < y_end; ++y) {
    uchar* out = dst.ptr(y);
    const __m512 bx = _mm512_set1_ps(float(m(0, 1) * y + m(0, 2))), by = _mm512_set1_ps(float(m(1, 1) * y + m(1, 2))),
                 bw = _mm512_set1_ps(float(m(2, 1) * y + m(2, 2)));
    for (int x = 0; x < dst.cols; x += 16) {
      const __m512 xs = _mm512_add_ps(_mm512_set1_ps(float(x)), lanes);
      const __m512 iw = _mm512_div_ps(_mm512_set1_ps(1.f), _mm512_fmadd_ps(m20, xs, bw));
      const __m512 fx = _mm512_mul_ps(_mm512_fmadd_ps(m00, xs, bx), iw);
      const __m512 fy = _mm512_mul_ps(_mm512_fmadd_ps(m10, xs, by), iw);
      const __m512 flx = _mm512_roundscale_ps(fx, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      const __m512 fly = _mm512_roundscale_ps(fy, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      // Not a number or past the int range: INT_MIN, outside.
      const __m512i ix = _mm512_cvttps_epi32(flx), iy = _mm512_cvttps_epi32(fly);
      __mmask16 inside = _mm512_cmpge_epi32_mask(ix, zero) & _mm512_cmplt_epi32_mask(ix, last_x) &
                         _mm512_cmpge_epi32_mask(iy, zero) & _mm512_cmplt_epi32_mask(iy, last_y);
      if (dst.cols - x < 16) inside &= static_cast<__mmask16>((1u << (dst.cols - x)) - 1);
      if (!inside) continue;
      const __mmask16 corner = _mm512_cmpeq_epi32_mask(ix, corner_x) & _mm512_cmpeq_epi32_mask(iy, corner_y);
      const __mmask16 gathered = inside & static_cast<__mmask16>(~corner);
      const __m512i at = _mm512_add_epi32(_mm512_mullo_epi32(iy, rows), _mm512_mullo_epi32(ix, three));
      const __m512i below = _mm512_add_epi32(at, rows);
      const __m512i taps[4] = {_mm512_mask_i32gather_epi32(zero, gathered, at, src.data, 1),
                               _mm512_mask_i32gather_epi32(zero, gathered, _mm512_add_epi32(at, three), src.data, 1),
                               _mm512_mask_i32gather_epi32(zero, gathered, below, src.data, 1),
                               _mm512_mask_i32gather_epi32(zero, gathered, _mm512_add_epi32(below, three), src.data, 1)};
      const __m512 ax = _mm512_sub_ps(fx, flx), ay = _mm512_sub_ps(fy, fly);
      alignas(64) int32_t value[3][16];
      for (int c = 0; c < 3; ++c) {
        const __m512i shift = _mm512_set1_epi32(8 * c);
        __m512 v[4];
        for (int k = 0; k < 4; ++k) v[k] = _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srlv_epi32(taps[k], shift), byte));
        const __m512 top = _mm512_fmadd_ps(ax, _mm512_sub_ps(v[1], v[0]), v[0]);
        const __m512 bottom = _mm512_fmadd_ps(ax, _mm512_sub_ps(v[3], v[2]), v[2]);
        _mm512_store_si512(value[c], _mm512_cvtps_epi32(_mm512_fmadd_ps(ay, _mm512_sub_ps(bottom, top), top)));
      }
      alignas(64) float px[16], py[16];
      if (corner) {
        _mm512_store_ps(px, fx);
        _mm512_store_ps(py, fy);
      }
      for (int i = 0; i < 16; ++i) {
        if (!((inside >> i) & 1)) continue;
        uchar* o = out + 3 * (x + i);
        if ((corner >> i) & 1) {
          InsidePixel(src, px[i], py[i], o);
          continue;
        }
        o[0] = static_cast<uchar>(value[0][i]);
        o[1] = static_cast<uchar>(value[1][i]);
        o[2] = static_cast<uchar>(value[2][i]);
      }
    }
  }
}

// The columns [*begin, *end) of output row y whose source positions (through `m`) do not lie
// more than two pixels beyond a `zero` edge of a `size` image; past those every tap is on that
// edge. Where the map's denominator is not positive along the row, the whole row.
void RowSpan(const cv::Matx33d& m, int y, int cols, cv::Size size, const CodeEdges& zero, int* begin, int* end) {
  *begin = 0, *end = cols;
  const double gy = m(2, 1) * y + m(2, 2);
  const double w0 = m(2, 0) * -1.0 + gy, w1 = m(2, 0) * (cols + 1.0) + gy;
  if (!(w0 > 1e-12 && w1 > 1e-12)) return;
  double lo = -1.0, hi = cols + 1.0;
  // The source coordinate r, (a x + b) / (g x + gy) with the denominator positive, at least
  // (or at most) v: a x + b - v (g x + gy) = k x - c >= 0 (or <= 0), a bound on x.
  const auto bound = [&](int r, double v, bool at_least) {
    const double a = m(r, 0), b = m(r, 1) * y + m(r, 2);
    const double k = a - v * m(2, 0), c = v * gy - b;
    if (std::abs(k) < 1e-12) {
      if (at_least ? c > 0 : c < 0) hi = lo - 1;  // no x
    } else if ((k > 0) == at_least) {
      lo = std::max(lo, c / k);
    } else {
      hi = std::min(hi, c / k);
    }
  };
  if (zero.left) bound(0, -2.0, true);
  if (zero.right) bound(0, size.width + 1.0, false);
  if (zero.top) bound(1, -2.0, true);
  if (zero.bottom) bound(1, size.height + 1.0, false);
  if (!(lo <= hi)) {
    *end = 0;
    return;
  }
  *begin = static_cast<int>(std::clamp(std::floor(lo) - 1, 0.0, double(cols)));
  *end = static_cast<int>(std::clamp(std::ceil(hi) + 2, 0.0, double(cols)));
}

void CheckType(const cv::Mat& src, const char* what) {
  if (src.type() != CV_8UC4 && src.type() != CV_16UC4)
    Fail(what, "image type " + cv::typeToString(src.type()) + " is not 8- or 16-bit BGRW");
}

}  // namespace

void WarpAccumulate(const cv::Mat& src, const cv::Matx33d& src_to_dst, const std::array<float, 256>& weight,
                    float unit, cv::Mat& sum, cv::Mat& weight_sum, const CodeEdges& zero) {
  CheckType(src, "bilinear warp into a canvas");
  CV_Assert(sum.type() == CV_32FC3 && weight_sum.type() == CV_32F && sum.size() == weight_sum.size());
  if (src.empty()) return;
  // Taps are 32-bit element offsets from the image's first pixel.
  if (static_cast<double>(src.step1()) * src.rows >= 2147483647.0)
    Fail("bilinear warp into a canvas", "a frame of " + std::to_string(src.cols) + " x " + std::to_string(src.rows) +
                                            " pixels is past 2^31 values");
  const cv::Matx33d dst_to_src = src_to_dst.inv();
  const bool skips = zero.left || zero.right || zero.top || zero.bottom;
  for (int y = 0; y < sum.rows; ++y) {
    int begin = 0, end = sum.cols;
    if (skips) RowSpan(dst_to_src, y, sum.cols, src.size(), zero, &begin, &end);
    if (begin >= end) continue;
    AccumulateSink sink{sum.ptr<cv::Vec3f>(y) + begin, weight_sum.ptr<float>(y) + begin, weight.data(), unit};
    if (sink.wide && CpuHasAvx2Fma()) {
      if (src.depth() == CV_8U)
        AccumulateRowAvx512<uint8_t>(src, dst_to_src, y, begin, end, sink);
      else
        AccumulateRowAvx512<uint16_t>(src, dst_to_src, y, begin, end, sink);
    } else if (src.depth() == CV_8U)
      Row<uint8_t>(src, dst_to_src, y, begin, end, sink);
    else
      Row<uint16_t>(src, dst_to_src, y, begin, end, sink);
  }
}

CodeEdges ZeroCodeEdges(const cv::Mat& bgrw) {
  CheckType(bgrw, "the feather code's edges");
  CodeEdges e;
  if (bgrw.empty()) return e;
  const auto zero = [&](int x, int y) {
    return bgrw.depth() == CV_8U ? bgrw.at<cv::Vec4b>(y, x)[3] == 0 : bgrw.at<cv::Vec4w>(y, x)[3] == 0;
  };
  e.left = e.right = e.top = e.bottom = true;
  for (int x = 0; x < bgrw.cols; ++x) {
    e.top = e.top && zero(x, 0);
    e.bottom = e.bottom && zero(x, bgrw.rows - 1);
  }
  for (int y = 0; y < bgrw.rows; ++y) {
    e.left = e.left && zero(0, y);
    e.right = e.right && zero(bgrw.cols - 1, y);
  }
  return e;
}

void WarpInside(const cv::Mat& src, const cv::Matx33d& dst_to_src, cv::Mat& dst) {
  // Taps are 32-bit byte offsets from the image's first pixel.
  const bool fits = static_cast<double>(src.step) * src.rows < 2147483647.0;
  if (!CpuHasAvx512() || src.type() != CV_8UC3 || dst.type() != CV_8UC3 || src.rows < 2 || src.cols < 2 || !fits) {
    cv::warpPerspective(src, dst, cv::Mat(dst_to_src), dst.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                        cv::BORDER_TRANSPARENT);
    return;
  }
  cv::parallel_for_(cv::Range(0, dst.rows),
                    [&](const cv::Range& r) { WarpInsideRows(src, dst_to_src, dst, r.start, r.end); });
}

}  // namespace rolamos
