#include "engine/canvas_rows.h"

#include <immintrin.h>

#include <cstdint>

#include "engine/feather.h"
#include "util/cpu_features.h"

namespace rolamos {
namespace {

// One row of a frame's 8-bit channels times the colour correction (one factor per channel, or
// none) and `scale`, rounded and saturated to 16 bits, as a flat run of values.
void CorrectRowScalar(const uchar* p, const float* c, float s, int n, ushort* out) {
  for (int i = 0; i < n; ++i) out[i] = cv::saturate_cast<ushort>(c ? float(p[i]) * c[i] * s : float(p[i]) * s);
}

__attribute__((target("avx2"))) void CorrectRowAvx2(const uchar* p, const float* c, float s, int n, ushort* out) {
  const __m256 scale = _mm256_set1_ps(s);
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    __m256 v = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + i))));
    if (c) v = _mm256_mul_ps(v, _mm256_loadu_ps(c + i));
    // Rounded to nearest as cvRound; past 65535 saturated by the pack (values stay far below 2^31).
    const __m256i q = _mm256_cvtps_epi32(_mm256_mul_ps(v, scale));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                     _mm_packus_epi32(_mm256_castsi256_si128(q), _mm256_extracti128_si256(q, 1)));
  }
  CorrectRowScalar(p + i, c ? c + i : nullptr, s, n - i, out + i);
}

// Pixels [0, n) of a row: corrected values (B, G, R, ...) and codes into (B, G, R, code) words.
void InterleaveRowScalar(const ushort* row, const uchar* code, int n, cv::Vec4w* out) {
  for (int x = 0; x < n; ++x) out[x] = cv::Vec4w(row[3 * x], row[3 * x + 1], row[3 * x + 2], code[x]);
}

// Eight pixels at a time: 24 values and 8 codes into 32 words by one permute.
__attribute__((target("avx512f,avx512bw"))) void InterleaveRowAvx512(const ushort* row, const uchar* code, int n,
                                                                    cv::Vec4w* out) {
  // Word 4p + c is value 3p + c (c < 3) of the 24, or code p (word 32 + p of the pair).
  static const struct Order {
    alignas(64) uint16_t word[32];
    Order() {
      for (int p = 0; p < 8; ++p)
        for (int c = 0; c < 4; ++c) word[4 * p + c] = static_cast<uint16_t>(c < 3 ? 3 * p + c : 32 + p);
    }
  } order;
  const __m512i idx = _mm512_load_si512(order.word);
  int x = 0;
  for (; x + 8 <= n; x += 8) {
    const __m512i values = _mm512_maskz_loadu_epi16(0xFFFFFF, row + 3 * x);
    const __m512i codes =
        _mm512_zextsi128_si512(_mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(code + x))));
    _mm512_storeu_si512(out + x, _mm512_permutex2var_epi16(values, idx, codes));
  }
  InterleaveRowScalar(row + 3 * x, code + x, n - x, out + x);
}

// One row of the working canvas's accumulation: pixels [0, n) of `px` (BGRW) into the sums from
// column `col` of a block, and into the 2 x 2 means' row: weight[code] x colour and weight[code]
// (code 0 adds nothing), each a quarter into its cell.
void AddReducedRowScalar(const cv::Vec4b* px, int n, int col, const float* table, cv::Vec3f* acc, float* wsum,
                         cv::Vec3f* small, float* small_w) {
  constexpr float kCell = 0.25f;
  for (int x = 0; x < n; ++x) {
    if (!px[x][3]) continue;
    const float a = table[px[x][3]];
    const cv::Vec3f c(a * px[x][0], a * px[x][1], a * px[x][2]);
    acc[x] += c;
    wsum[x] += a;
    const int cell = (col + x) / 2;
    small[cell] += c * kCell;
    small_w[cell] += a * kCell;
  }
}

// The same sixteen pixels (eight cells) at a time with AVX-512 from an even column: each sum
// gets the same products in the same order (a cell its even pixel's, then its odd one's; code 0
// adds +0, which leaves a sum of non-negative values as it was).
// Sixteen pixels' B, G, R interleaved as the sums hold them: value v = 16 j + i of vector j is
// channel v % 3 of pixel v / 3. Eight (the 2 x 2 cells) take the first 24 values, the same lanes.
struct BgrLayout {
  alignas(64) int32_t pixel[3][16];  // v / 3: R (and any channel) from its pixel's lane
  alignas(64) int32_t bg[3][16];     // B from the first source's lane, G from the second's
  BgrLayout() {
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 16; ++i) {
        const int v = 16 * j + i, p = v / 3;
        pixel[j][i] = p;
        bg[j][i] = v % 3 == 0 ? p : 16 + p;
      }
  }
};
const BgrLayout kBgr;

// Lanes of an interleaved vector j (16 values) that hold R: value 16 j + i with (16 j + i) % 3 == 2.
constexpr __mmask16 RedLanes(int j) {
  __mmask16 m = 0;
  for (int i = 0; i < 16; ++i)
    if ((16 * j + i) % 3 == 2) m = static_cast<__mmask16>(m | (1u << i));
  return m;
}

// Vector j of the interleaved values of B, G and R.
__attribute__((target("avx512f"))) inline __m512 Interleaved(int j, __m512 b, __m512 g, __m512 r) {
  const __m512 two = _mm512_permutex2var_ps(b, _mm512_load_si512(kBgr.bg[j]), g);
  return _mm512_mask_permutexvar_ps(two, RedLanes(j), _mm512_load_si512(kBgr.pixel[j]), r);
}

__attribute__((target("avx512f"))) void AddReducedRowAvx512(const cv::Vec4b* px, int n, int col, const float* table,
                                                            cv::Vec3f* acc, float* wsum, cv::Vec3f* small,
                                                            float* small_w) {
  int x = 0;
  if ((col & 1) && n > 0) {  // an odd first column: its cell's even pixel is not in this segment
    AddReducedRowScalar(px, 1, col, table, acc, wsum, small, small_w);
    x = 1;
  }
  const __m512i byte = _mm512_set1_epi32(0xFF), zero = _mm512_setzero_si512();
  const __m512 quarter = _mm512_set1_ps(0.25f);
  for (; x + 16 <= n; x += 16) {
    const __m512i v = _mm512_loadu_si512(px + x);
    const __m512i code = _mm512_srli_epi32(v, 24);
    const __mmask16 used = _mm512_cmpneq_epi32_mask(code, zero);
    const __m512 a = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), used, code, table, 4);
    const __m512 cb = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(v, byte)));
    const __m512 cg = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(v, 8), byte)));
    const __m512 cr = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(v, 16), byte)));
    float* s = acc[x].val;
    _mm512_storeu_ps(s, _mm512_add_ps(_mm512_loadu_ps(s), Interleaved(0, cb, cg, cr)));
    _mm512_storeu_ps(s + 16,
                     _mm512_add_ps(_mm512_loadu_ps(s + 16), Interleaved(1, cb, cg, cr)));
    _mm512_storeu_ps(s + 32,
                     _mm512_add_ps(_mm512_loadu_ps(s + 32), Interleaved(2, cb, cg, cr)));
    _mm512_storeu_ps(wsum + x, _mm512_add_ps(_mm512_loadu_ps(wsum + x), a));
    // The cells: each quarter, even pixels then odd ones.
    // A vector's even and odd lanes into lanes 0..7 (the upper eight: unused).
    const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 0, 2, 4, 6, 8, 10, 12, 14);
    const __m512i odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 1, 3, 5, 7, 9, 11, 13, 15);
    const __m512 qb = _mm512_mul_ps(cb, quarter), qg = _mm512_mul_ps(cg, quarter), qr = _mm512_mul_ps(cr, quarter);
    const __m512 qa = _mm512_mul_ps(a, quarter);
    const __m512 eb = _mm512_permutexvar_ps(even, qb), eg = _mm512_permutexvar_ps(even, qg),
                 er = _mm512_permutexvar_ps(even, qr);
    const __m512 ob = _mm512_permutexvar_ps(odd, qb), og = _mm512_permutexvar_ps(odd, qg),
                 orr = _mm512_permutexvar_ps(odd, qr);
    float* c = small[(col + x) / 2].val;
    const __mmask16 first8 = 0xFF;
    // The eight cells' values are the first 24 of an interleaving (e1, o1: their first 8 lanes).
    const __m512 e0 = Interleaved(0, eb, eg, er), e1 = Interleaved(1, eb, eg, er);
    const __m512 o0 = Interleaved(0, ob, og, orr), o1 = Interleaved(1, ob, og, orr);
    _mm512_storeu_ps(c, _mm512_add_ps(_mm512_add_ps(_mm512_loadu_ps(c), e0), o0));
    _mm512_mask_storeu_ps(c + 16, first8,
                          _mm512_add_ps(_mm512_add_ps(_mm512_maskz_loadu_ps(first8, c + 16), e1), o1));
    float* w = small_w + (col + x) / 2;
    const __m512 we = _mm512_permutexvar_ps(even, qa), wo = _mm512_permutexvar_ps(odd, qa);
    _mm512_mask_storeu_ps(w, first8, _mm512_add_ps(_mm512_add_ps(_mm512_maskz_loadu_ps(first8, w), we), wo));
  }
  AddReducedRowScalar(px + x, n - x, col + x, table, acc + x, wsum + x, small, small_w);
}

// Pixels [0, n) of a rendered row: where the weight passes kAlphaCut, the sums over the weight
// (times 1 / weight, rounded and saturated as cv::saturate_cast does) and alpha 255; elsewhere
// all zero.
void RenderRowScalar(const cv::Vec3f* s, const float* w, int n, cv::Vec4b* o) {
  for (int x = 0; x < n; ++x) {
    if (w[x] <= kAlphaCut) {
      o[x] = cv::Vec4b(0, 0, 0, 0);
      continue;
    }
    const float k = 1.0f / w[x];
    o[x] = cv::Vec4b(cv::saturate_cast<uchar>(s[x][0] * k), cv::saturate_cast<uchar>(s[x][1] * k),
                     cv::saturate_cast<uchar>(s[x][2] * k), 255);
  }
}

// Sixteen pixels at a time (AVX-512 VBMI): the same products, rounded to nearest even as
// cvRound, clamped to 0..255, and the bytes laid out BGRA by one permute.
__attribute__((target("avx512f,avx512bw,avx512vbmi,bmi2"))) void RenderRowAvx512(const cv::Vec3f* s, const float* w,
                                                                                 int n, cv::Vec4b* o) {
  // Output byte 4p + c is value 3p + c (c < 3) of the 48, or alpha (from a vector of 255s).
  static const struct Layout {
    alignas(64) uint8_t byte[64];
    Layout() {
      for (int p = 0; p < 16; ++p)
        for (int c = 0; c < 4; ++c) byte[4 * p + c] = static_cast<uint8_t>(c < 3 ? 3 * p + c : 64);
    }
  } layout;
  const __m512i lay = _mm512_load_si512(layout.byte), opaque = _mm512_set1_epi8(char(0xFF));
  const __m512 cut = _mm512_set1_ps(kAlphaCut), one = _mm512_set1_ps(1.0f);
  const __m512i zero = _mm512_setzero_si512();
  int x = 0;
  for (; x + 16 <= n; x += 16) {
    const __m512 weight = _mm512_loadu_ps(w + x);
    const __mmask16 data = _mm512_cmp_ps_mask(weight, cut, _CMP_GT_OQ);
    const __m512 k = _mm512_div_ps(one, weight);
    const float* sums = s[x].val;
    __m128i bytes[3];
    for (int j = 0; j < 3; ++j) {
      const __m512 kj = _mm512_permutexvar_ps(_mm512_load_si512(kBgr.pixel[j]), k);  // each value's pixel's
      const __m512i v = _mm512_max_epi32(_mm512_cvtps_epi32(_mm512_mul_ps(_mm512_loadu_ps(sums + 16 * j), kj)), zero);
      bytes[j] = _mm512_cvtusepi32_epi8(v);
    }
    // The 48 values' bytes in the low 48 bytes of one vector.
    const __m512i values = _mm512_inserti32x4(
        _mm512_inserti32x4(_mm512_castsi128_si512(bytes[0]), bytes[1], 1), bytes[2], 2);
    const __m512i bgra = _mm512_permutex2var_epi8(values, lay, opaque);
    // Pixels without data: all four bytes zero.
    const __mmask64 keep = _pdep_u64(data, 0x1111111111111111ull) * 0xF;  // each pixel's bit for its 4 bytes
    _mm512_storeu_si512(o + x, _mm512_maskz_mov_epi8(keep, bgra));
  }
  RenderRowScalar(s + x, w + x, n - x, o + x);
}

}  // namespace

void CorrectRow(const uchar* p, const float* c, float s, int n, ushort* out) {
  (CpuHasAvx2() ? CorrectRowAvx2 : CorrectRowScalar)(p, c, s, n, out);
}

void InterleaveDeepRow(const ushort* row, const uchar* code, int n, cv::Vec4w* out) {
  (CpuHasAvx512Bw() ? InterleaveRowAvx512 : InterleaveRowScalar)(row, code, n, out);
}

void AddReducedRow(const cv::Vec4b* px, int n, int col, const float* weight, cv::Vec3f* acc, float* wsum,
                   cv::Vec3f* small, float* small_w) {
  (CpuHasAvx512() ? AddReducedRowAvx512 : AddReducedRowScalar)(px, n, col, weight, acc, wsum, small, small_w);
}

void RenderSumsRow(const cv::Vec3f* sum, const float* weight, int n, cv::Vec4b* out) {
  (CpuHasAvx512Vbmi() ? RenderRowAvx512 : RenderRowScalar)(sum, weight, n, out);
}

}  // namespace rolamos
