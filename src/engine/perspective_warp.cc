#include "engine/perspective_warp.h"

#include <algorithm>
#include <climits>
#include <cstdint>

#include <immintrin.h>
#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

constexpr int kTabBits = 5;  // OpenCV's INTER_BITS: sources rounded to 1/32 pixel
constexpr int kTab = 1 << kTabBits;

// OpenCV's bilinear table holds (32 - ay)(32 - ax) x 32 and its kin (exact products, summing to
// 32768), and rounds the sum over 15 bits; here the same without the common factor 32.
constexpr int kWeightBits = 2 * kTabBits;

// The sources of eight destination pixels x1 .. x1 + 7 of a block whose first pixel's source
// (homogeneous, before dividing) is X0, Y0, W0: in 1/32 pixels, as OpenCV rounds them.
struct Sources {
  __m256i x, y;
};

__attribute__((target("avx512f,avx512vl,avx2"))) Sources SourcesAt(const double* M, double X0, double Y0, double W0,
                                                                    int x1) {
  const __m512d x = _mm512_add_pd(_mm512_set1_pd(double(x1)), _mm512_setr_pd(0, 1, 2, 3, 4, 5, 6, 7));
  const __m512d zero = _mm512_setzero_pd();
  __m512d w = _mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(M[6]), x), _mm512_set1_pd(W0));
  // W ? 32 / W : 0
  w = _mm512_maskz_div_pd(_mm512_cmp_pd_mask(w, zero, _CMP_NEQ_UQ), _mm512_set1_pd(double(kTab)), w);
  const __m512d lo = _mm512_set1_pd(double(INT_MIN)), hi = _mm512_set1_pd(double(INT_MAX));
  const __m512d fx = _mm512_max_pd(
      lo, _mm512_min_pd(hi, _mm512_mul_pd(_mm512_add_pd(_mm512_set1_pd(X0), _mm512_mul_pd(_mm512_set1_pd(M[0]), x)), w)));
  const __m512d fy = _mm512_max_pd(
      lo, _mm512_min_pd(hi, _mm512_mul_pd(_mm512_add_pd(_mm512_set1_pd(Y0), _mm512_mul_pd(_mm512_set1_pd(M[3]), x)), w)));
  return {_mm512_cvtpd_epi32(fx), _mm512_cvtpd_epi32(fy)};  // rounded to nearest, as cvRound
}

// One destination pixel from its source (sx, sy: whole pixels, saturated to 16 bits as OpenCV
// keeps them; ax, ay: 32nds) by OpenCV's rules for a source partly or wholly outside: the
// reflected borders (the replicated one is clamped sixteen pixels at a time).
template <int CN>
void BorderPixel(const cv::Mat& src, int sx, int sy, int ax, int ay, int border, uchar* out) {
  const int x0 = cv::borderInterpolate(sx, src.cols, border), x1 = cv::borderInterpolate(sx + 1, src.cols, border);
  const int y0 = cv::borderInterpolate(sy, src.rows, border), y1 = cv::borderInterpolate(sy + 1, src.rows, border);
  const int w00 = (kTab - ay) * (kTab - ax), w01 = (kTab - ay) * ax, w10 = ay * (kTab - ax), w11 = ay * ax;
  const uchar *r0 = src.ptr<uchar>(y0), *r1 = src.ptr<uchar>(y1);
  for (int c = 0; c < CN; ++c) {
    const int v = r0[x0 * CN + c] * w00 + r0[x1 * CN + c] * w01 + r1[x0 * CN + c] * w10 + r1[x1 * CN + c] * w11;
    out[c] = static_cast<uchar>((v + (1 << (kWeightBits - 1))) >> kWeightBits);
  }
}

// The interpolation of one channel from its four taps (int32 lanes holding 0..255).
__attribute__((target("avx512f,avx512vl,avx2"))) __m512i Interpolate(__m512i v00, __m512i v01, __m512i v10,
                                                                      __m512i v11, __m512i w00, __m512i w01,
                                                                      __m512i w10, __m512i w11) {
  const __m512i sum = _mm512_add_epi32(_mm512_add_epi32(_mm512_mullo_epi32(v00, w00), _mm512_mullo_epi32(v01, w01)),
                                       _mm512_add_epi32(_mm512_mullo_epi32(v10, w10), _mm512_mullo_epi32(v11, w11)));
  return _mm512_srai_epi32(_mm512_add_epi32(sum, _mm512_set1_epi32(1 << (kWeightBits - 1))), kWeightBits);
}

// Each lane's byte at `shift` bits.
__attribute__((target("avx512f"))) __m512i Byte(__m512i v, unsigned shift) {
  return _mm512_and_si512(_mm512_srli_epi32(v, shift), _mm512_set1_epi32(0xFF));
}

// The image's bytes at `at` (byte offsets of pixels from its first), one per lane: each read as
// the 32-bit word that ends at it (or, in the image's first three bytes, starts at the first), so
// never past the image's last pixel (Handled asks for at least 4 bytes).
__attribute__((target("avx512f"))) __m512i GatherBytes(const uchar* base, __m512i at, __mmask16 lanes) {
  const __m512i from = _mm512_max_epi32(_mm512_sub_epi32(at, _mm512_set1_epi32(3)), _mm512_setzero_si512());
  const __m512i word = _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), lanes, from, base, 1);
  const __m512i shift = _mm512_slli_epi32(_mm512_sub_epi32(at, from), 3);
  return _mm512_and_si512(_mm512_srlv_epi32(word, shift), _mm512_set1_epi32(0xFF));
}

// Where sixteen destination pixels read: the four taps' byte offsets, and the weights.
struct Taps {
  __m512i at00, at01, at10, at11;
  __m512i w00, w01, w10, w11;
};

// Taps at columns x0, x1 and rows y0, y1 (inside the image), from the 32nds ax, ay.
template <int CN>
__attribute__((target("avx512f"))) Taps TapsAt(const cv::Mat& src, __m512i x0, __m512i x1, __m512i y0, __m512i y1,
                                                __m512i ax, __m512i ay) {
  const __m512i tab = _mm512_set1_epi32(kTab), step = _mm512_set1_epi32(int(src.step)), cn = _mm512_set1_epi32(CN);
  Taps t;
  const __m512i r0 = _mm512_mullo_epi32(y0, step), r1 = _mm512_mullo_epi32(y1, step);
  const __m512i c0 = _mm512_mullo_epi32(x0, cn), c1 = _mm512_mullo_epi32(x1, cn);
  t.at00 = _mm512_add_epi32(r0, c0), t.at01 = _mm512_add_epi32(r0, c1);
  t.at10 = _mm512_add_epi32(r1, c0), t.at11 = _mm512_add_epi32(r1, c1);
  t.w00 = _mm512_mullo_epi32(_mm512_sub_epi32(tab, ay), _mm512_sub_epi32(tab, ax));
  t.w01 = _mm512_mullo_epi32(_mm512_sub_epi32(tab, ay), ax);
  t.w10 = _mm512_mullo_epi32(ay, _mm512_sub_epi32(tab, ax));
  t.w11 = _mm512_mullo_epi32(ay, ax);
  return t;
}

// Sixteen pixels (`lanes`) from their taps. `pairs`: a single channel's two taps of a row read as
// one word (each tap's row holds 4 bytes from it).
template <int CN>
__attribute__((target("avx512f,avx512vl,avx512bw,avx2"))) void Blend(const cv::Mat& src, const Taps& t,
                                                                     __mmask16 lanes, bool pairs, uchar* out) {
  const uchar* base = src.data;
  const __m512i zero = _mm512_setzero_si512();
  if (CN == 1) {
    __m512i v00, v01, v10, v11;
    if (pairs) {
      const __m512i top = _mm512_mask_i32gather_epi32(zero, lanes, t.at00, base, 1);
      const __m512i bottom = _mm512_mask_i32gather_epi32(zero, lanes, t.at10, base, 1);
      v00 = Byte(top, 0), v01 = Byte(top, 8), v10 = Byte(bottom, 0), v11 = Byte(bottom, 8);
    } else {
      v00 = GatherBytes(base, t.at00, lanes), v01 = GatherBytes(base, t.at01, lanes);
      v10 = GatherBytes(base, t.at10, lanes), v11 = GatherBytes(base, t.at11, lanes);
    }
    _mm_mask_storeu_epi8(out, lanes, _mm512_cvtepi32_epi8(Interpolate(v00, v01, v10, v11, t.w00, t.w01, t.w10, t.w11)));
  } else {
    const __m512i p00 = _mm512_mask_i32gather_epi32(zero, lanes, t.at00, base, 1);
    const __m512i p01 = _mm512_mask_i32gather_epi32(zero, lanes, t.at01, base, 1);
    const __m512i p10 = _mm512_mask_i32gather_epi32(zero, lanes, t.at10, base, 1);
    const __m512i p11 = _mm512_mask_i32gather_epi32(zero, lanes, t.at11, base, 1);
    __m512i packed = zero;
    for (unsigned shift = 0; shift < 32; shift += 8) {
      const __m512i v = Interpolate(Byte(p00, shift), Byte(p01, shift), Byte(p10, shift), Byte(p11, shift), t.w00,
                                    t.w01, t.w10, t.w11);
      packed = _mm512_or_si512(packed, _mm512_slli_epi32(v, shift));
    }
    _mm512_mask_storeu_epi32(out, lanes, packed);
  }
}

// permutex2var indices that interleave three 16-lane vectors into three chunks of 16: chunk k
// lane j is value 16 k + j, pixel p = (16 k + j) / 3 of channel (16 k + j) % 3. `first` takes
// channels 0 and 1 (lanes of the first and second vector), `second` keeps those and takes
// channel 2's from the third.
struct Interleave3 {
  alignas(64) int32_t first[3][16];
  alignas(64) int32_t second[3][16];
  Interleave3() {
    for (int k = 0; k < 3; ++k)
      for (int j = 0; j < 16; ++j) {
        const int g = 16 * k + j, p = g / 3, c = g % 3;
        first[k][j] = c == 1 ? 16 + p : p;
        second[k][j] = c == 2 ? 16 + p : j;
      }
  }
};

// Sixteen destination pixels' sources: whole pixels (saturated to 16 bits, as OpenCV keeps them),
// 32nds, and the lanes that are pixels of the row.
struct Sixteen {
  __m512i sx, sy, ax, ay;
  __mmask16 lanes;
};

// Rows [y0, y1) of a `dst` sized destination, sixteen pixels at a time: pixels.Put(y, x, s) for
// the pixels x .. x + 15 of row y. OpenCV's blocks: 16 rows (fewer in a shorter image) of up to
// 1024 / 16 = 64 pixels; each row of a block starts from its first pixel's source.
template <class Pixels>
__attribute__((target("avx512f,avx512vl,avx512bw,avx2"))) void ForEachSixteen(cv::Size dst, const double* M, int y0,
                                                                             int y1, Pixels& pixels) {
  const int block_w = std::min(1024 / std::min(16, dst.height), dst.width);
  for (int y = y0; y < y1; ++y)
    for (int xb = 0; xb < dst.width; xb += block_w) {
      const int bw = std::min(block_w, dst.width - xb);
      // In OpenCV's order of operations (no fused multiply-adds).
      const double a = M[0] * xb, b = M[1] * y, c = M[3] * xb, d = M[4] * y, e = M[6] * xb, f = M[7] * y;
      const double X0 = a + b + M[2], Y0 = c + d + M[5], W0 = e + f + M[8];
      for (int x1 = 0; x1 < bw; x1 += 16) {
        const int n = std::min(16, bw - x1);
        const Sources s0 = SourcesAt(M, X0, Y0, W0, x1), s1 = SourcesAt(M, X0, Y0, W0, x1 + 8);
        const __m512i X = _mm512_inserti64x4(_mm512_castsi256_si512(s0.x), s1.x, 1);
        const __m512i Y = _mm512_inserti64x4(_mm512_castsi256_si512(s0.y), s1.y, 1);
        const __m512i low = _mm512_set1_epi32(SHRT_MIN), high = _mm512_set1_epi32(SHRT_MAX);
        const __m512i frac = _mm512_set1_epi32(kTab - 1);
        Sixteen s;
        s.sx = _mm512_min_epi32(_mm512_max_epi32(_mm512_srai_epi32(X, kTabBits), low), high);
        s.sy = _mm512_min_epi32(_mm512_max_epi32(_mm512_srai_epi32(Y, kTabBits), low), high);
        s.ax = _mm512_and_si512(X, frac), s.ay = _mm512_and_si512(Y, frac);
        s.lanes = static_cast<__mmask16>(n == 16 ? 0xFFFF : (1u << n) - 1);
        pixels.Put(y, xb + x1, s);
      }
    }
}

// 8-bit pixels (CN 1 or 4) with a replicated or reflected border.
template <int CN>
struct BytePixels {
  const cv::Mat& src;
  cv::Mat& dst;
  int border;

  __attribute__((target("avx512f,avx512vl,avx512bw,avx2"))) void Put(int y, int x, const Sixteen& s) {
    const __m512i zero = _mm512_setzero_si512(), one = _mm512_set1_epi32(1);
    // A single channel's pair of taps is read as a word: where it lies in the row.
    const int pair_x = CN == 1 ? src.cols - 4 : src.cols - 2;
    const __mmask16 inside = s.lanes & _mm512_cmp_epi32_mask(s.sx, zero, _MM_CMPINT_NLT) &
                             _mm512_cmp_epi32_mask(s.sx, _mm512_set1_epi32(pair_x), _MM_CMPINT_LE) &
                             _mm512_cmp_epi32_mask(s.sy, zero, _MM_CMPINT_NLT) &
                             _mm512_cmp_epi32_mask(s.sy, _mm512_set1_epi32(src.rows - 2), _MM_CMPINT_LE);
    uchar* out = dst.ptr<uchar>(y) + size_t(x) * CN;
    const __m512i sx1 = _mm512_add_epi32(s.sx, one), sy1 = _mm512_add_epi32(s.sy, one);
    if (inside == s.lanes) {
      Blend<CN>(src, TapsAt<CN>(src, s.sx, sx1, s.sy, sy1, s.ax, s.ay), s.lanes, true, out);
      return;
    }
    if (border == cv::BORDER_REPLICATE) {
      // Every tap clamped into the image: OpenCV's replicated border, and the same taps inside.
      const __m512i last_col = _mm512_set1_epi32(src.cols - 1), last_row = _mm512_set1_epi32(src.rows - 1);
      const __m512i x0 = _mm512_min_epi32(_mm512_max_epi32(s.sx, zero), last_col);
      const __m512i x1 = _mm512_min_epi32(_mm512_max_epi32(sx1, zero), last_col);
      const __m512i y0 = _mm512_min_epi32(_mm512_max_epi32(s.sy, zero), last_row);
      const __m512i y1 = _mm512_min_epi32(_mm512_max_epi32(sy1, zero), last_row);
      Blend<CN>(src, TapsAt<CN>(src, x0, x1, y0, y1, s.ax, s.ay), s.lanes, false, out);
      return;
    }
    if (inside) Blend<CN>(src, TapsAt<CN>(src, s.sx, sx1, s.sy, sy1, s.ax, s.ay), inside, true, out);
    alignas(64) int sxs[16], sys[16], axs[16], ays[16];
    _mm512_store_si512(sxs, s.sx);
    _mm512_store_si512(sys, s.sy);
    _mm512_store_si512(axs, s.ax);
    _mm512_store_si512(ays, s.ay);
    for (unsigned m = s.lanes & ~inside; m; m &= m - 1) {
      const int i = __builtin_ctz(m);
      BorderPixel<CN>(src, sxs[i], sys[i], axs[i], ays[i], border, out + i * CN);
    }
  }
};

// Float pixels (CN 1 or 3) with a border of zeros: OpenCV's float table (the same exact products
// as its fixed-point one, over 1024) and its sum, ((v00 w00 + v01 w01) + v10 w10) + v11 w11, each
// product and sum rounded; a tap outside counts as 0 in the same sum, as OpenCV's does.
template <int CN>
struct FloatPixels {
  const cv::Mat& src;
  cv::Mat& dst;

  __attribute__((target("avx512f,avx512vl,avx512bw,avx2"))) void Put(int y, int x, const Sixteen& s) {
    const __m512i zero = _mm512_setzero_si512(), one = _mm512_set1_epi32(1), tab = _mm512_set1_epi32(kTab);
    const __m512i sx1 = _mm512_add_epi32(s.sx, one), sy1 = _mm512_add_epi32(s.sy, one);
    const __m512i cols = _mm512_set1_epi32(src.cols), rows = _mm512_set1_epi32(src.rows);
    const __mmask16 x0 = _mm512_cmp_epi32_mask(s.sx, zero, _MM_CMPINT_NLT) & _mm512_cmp_epi32_mask(s.sx, cols, _MM_CMPINT_LT);
    const __mmask16 x1 = _mm512_cmp_epi32_mask(sx1, zero, _MM_CMPINT_NLT) & _mm512_cmp_epi32_mask(sx1, cols, _MM_CMPINT_LT);
    const __mmask16 y0 = _mm512_cmp_epi32_mask(s.sy, zero, _MM_CMPINT_NLT) & _mm512_cmp_epi32_mask(s.sy, rows, _MM_CMPINT_LT);
    const __mmask16 y1 = _mm512_cmp_epi32_mask(sy1, zero, _MM_CMPINT_NLT) & _mm512_cmp_epi32_mask(sy1, rows, _MM_CMPINT_LT);
    const __mmask16 m00 = s.lanes & x0 & y0, m01 = s.lanes & x1 & y0, m10 = s.lanes & x0 & y1, m11 = s.lanes & x1 & y1;
    const __m512i step = _mm512_set1_epi32(int(src.step / sizeof(float))), cn = _mm512_set1_epi32(CN);
    const __m512i at00 = _mm512_add_epi32(_mm512_mullo_epi32(s.sy, step), _mm512_mullo_epi32(s.sx, cn));
    const __m512i at01 = _mm512_add_epi32(at00, cn), at10 = _mm512_add_epi32(at00, step);
    const __m512i at11 = _mm512_add_epi32(at10, cn);
    const __m512 unit = _mm512_set1_ps(1.f / float(kTab * kTab));
    const __m512i rx = _mm512_sub_epi32(tab, s.ax), ry = _mm512_sub_epi32(tab, s.ay);
    const __m512 w00 = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_mullo_epi32(ry, rx)), unit);
    const __m512 w01 = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_mullo_epi32(ry, s.ax)), unit);
    const __m512 w10 = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_mullo_epi32(s.ay, rx)), unit);
    const __m512 w11 = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_mullo_epi32(s.ay, s.ax)), unit);
    const float* base = src.ptr<float>();
    const __m512 fzero = _mm512_setzero_ps();
    __m512 v[CN];
    for (int c = 0; c < CN; ++c) {
      const __m512i k = _mm512_set1_epi32(c);
      const __m512 t00 = _mm512_mask_i32gather_ps(fzero, m00, _mm512_add_epi32(at00, k), base, 4);
      const __m512 t01 = _mm512_mask_i32gather_ps(fzero, m01, _mm512_add_epi32(at01, k), base, 4);
      const __m512 t10 = _mm512_mask_i32gather_ps(fzero, m10, _mm512_add_epi32(at10, k), base, 4);
      const __m512 t11 = _mm512_mask_i32gather_ps(fzero, m11, _mm512_add_epi32(at11, k), base, 4);
      v[c] = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(t00, w00), _mm512_mul_ps(t01, w01)),
                                         _mm512_mul_ps(t10, w10)),
                           _mm512_mul_ps(t11, w11));
    }
    float* out = dst.ptr<float>(y) + size_t(x) * CN;
    if (CN == 1) {
      _mm512_mask_storeu_ps(out, s.lanes, v[0]);
      return;
    }
    // Three channel vectors interleaved into 48 values: each chunk's first two channels' lanes
    // picked from (v0, v1), then the third's from v2.
    static const Interleave3 order;
    const int values = __builtin_popcount(s.lanes) * 3;
    for (int k = 0; k < 3; ++k) {
      const __m512 ab = _mm512_permutex2var_ps(v[0], _mm512_load_si512(order.first[k]), v[CN > 1 ? 1 : 0]);
      const __m512 all = _mm512_permutex2var_ps(ab, _mm512_load_si512(order.second[k]), v[CN > 2 ? 2 : 0]);
      const int left = std::clamp(values - 16 * k, 0, 16);
      _mm512_mask_storeu_ps(out + 16 * k, static_cast<__mmask16>(left == 16 ? 0xFFFF : (1u << left) - 1), all);
    }
  }
};

bool Handled(const cv::Mat& src, cv::Size size, int flags, int border) {
  const bool bytes = (src.type() == CV_8UC1 || src.type() == CV_8UC4) &&
                     (border == cv::BORDER_REPLICATE || border == cv::BORDER_REFLECT || border == cv::BORDER_REFLECT_101);
  const bool floats = (src.type() == CV_32FC1 || src.type() == CV_32FC3) && border == cv::BORDER_CONSTANT;
  // Gathers take 32-bit byte offsets.
  const bool fits = double(src.step) * (src.rows + 1) < 2147483647.0;
  // A byte is gathered as the word that ends at it: the image holds at least one word.
  const bool word = double(src.step) * (src.rows - 1) + double(src.cols) * src.channels() >= 4;
  return CpuHasAvx512Bw() && (bytes || floats) && (flags & ~cv::WARP_INVERSE_MAP) == cv::INTER_LINEAR && fits &&
         word && src.cols >= 1 && src.rows >= 1 && size.width > 0 && size.height > 0;
}

}  // namespace

void WarpPerspectiveLinear(const cv::Mat& src, cv::Mat& dst, const cv::Matx33d& M, cv::Size size, int flags,
                           int border) {
  if (!Handled(src, size, flags, border)) {
    cv::warpPerspective(src, dst, cv::Mat(M), size, flags, border);
    return;
  }
  // As OpenCV: a map from source to destination is inverted (its 3 x 3 LU inverse) in double.
  cv::Mat m(3, 3, CV_64F);
  cv::Mat(M).copyTo(m);
  if (!(flags & cv::WARP_INVERSE_MAP)) cv::invert(m, m);
  const double* d = m.ptr<double>();
  cv::Mat out(size, src.type());
  cv::parallel_for_(cv::Range(0, size.height), [&](const cv::Range& r) {
    switch (src.type()) {
      case CV_8UC1: {
        BytePixels<1> p{src, out, border};
        return ForEachSixteen(size, d, r.start, r.end, p);
      }
      case CV_8UC4: {
        BytePixels<4> p{src, out, border};
        return ForEachSixteen(size, d, r.start, r.end, p);
      }
      case CV_32FC1: {
        FloatPixels<1> p{src, out};
        return ForEachSixteen(size, d, r.start, r.end, p);
      }
      default: {
        FloatPixels<3> p{src, out};
        return ForEachSixteen(size, d, r.start, r.end, p);
      }
    }
  }, double(size.area()) / double(1 << 16));
  dst = out;
}

}  // namespace rolamos
