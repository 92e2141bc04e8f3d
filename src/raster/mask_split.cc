#include "raster/mask_split.h"

#include <array>
#include <cstdint>

#include <immintrin.h>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

// A byte's bits in the other order: the mask's first pixel is its byte's highest bit.
const std::array<uint8_t, 256>& Reversed() {
  static const std::array<uint8_t, 256> table = [] {
    std::array<uint8_t, 256> t{};
    for (int v = 0; v < 256; ++v)
      for (int k = 0; k < 8; ++k)
        if (v & (1 << k)) t[size_t(v)] |= uint8_t(0x80 >> k);
    return t;
  }();
  return table;
}

struct Sums {
  uint64_t colour[3] = {0, 0, 0};
  uint64_t count = 0;
};

// Pixels [x, cols) of a row, one at a time: colour, bits (x a multiple of 8) and the sums.
void SplitRowFrom(const uchar* in, int cols, int cn, int x, uchar* colour, uchar* bits, Sums* s) {
  const int n = cn - 1;
  for (; x < cols; x += 8) {
    uint8_t byte = 0;
    for (int k = 0; k < 8; ++k) {
      const uchar* p = in + size_t(x + k) * size_t(cn);
      const bool data = p[n] >= 128;
      byte = uint8_t(byte << 1) | uint8_t(data);
      for (int c = 0; c < n; ++c) {
        colour[size_t(x + k) * size_t(n) + size_t(c)] = p[c];
        if (data) s->colour[c] += p[c];
      }
      s->count += data;
    }
    bits[x / 8] = byte;
  }
}

// The RGB bytes of 16 RGBA pixels, in order, in the first 48 bytes.
__attribute__((target("avx512f,avx512bw,avx512vbmi"))) __m512i RgbIndex() {
  alignas(64) uint8_t idx[64] = {};
  for (int j = 0; j < 48; ++j) idx[j] = uint8_t((j / 3) * 4 + j % 3);
  return _mm512_load_si512(idx);
}

// An RGBA row sixteen pixels at a time (the rest one at a time).
__attribute__((target("avx512f,avx512bw,avx512vbmi,bmi2,popcnt"))) void SplitRgbaRow(const uchar* in, int cols,
                                                                                     uchar* colour, uchar* bits,
                                                                                     Sums* s) {
  const __m512i rgb = RgbIndex(), zero = _mm512_setzero_si512();
  const std::array<uint8_t, 256>& reversed = Reversed();
  __m512i sum[3] = {zero, zero, zero};
  int x = 0;
  for (; x + 16 <= cols; x += 16) {
    const __m512i v = _mm512_loadu_si512(in + 4 * x);
    // Each alpha byte's top bit: alpha >= 128.
    const uint32_t data = uint32_t(_pext_u64(_mm512_movepi8_mask(v), 0x8888888888888888ull));
    s->count += uint64_t(_mm_popcnt_u32(data));
    _mm512_mask_storeu_epi8(colour + 3 * x, 0xFFFFFFFFFFFFull, _mm512_permutexvar_epi8(rgb, v));
    const uint64_t bytes = _pdep_u64(data, 0x1111111111111111ull);  // each data pixel's first byte
    for (int c = 0; c < 3; ++c)
      sum[c] = _mm512_add_epi64(sum[c], _mm512_sad_epu8(_mm512_maskz_mov_epi8(bytes << c, v), zero));
    bits[x / 8] = reversed[data & 0xFF];
    bits[x / 8 + 1] = reversed[data >> 8];
  }
  for (int c = 0; c < 3; ++c) s->colour[c] += uint64_t(_mm512_reduce_add_epi64(sum[c]));
  SplitRowFrom(in, cols, 4, x, colour, bits, s);
}

// The pixels without data of an RGB row (from the row's packed bits) set to `fill`.
__attribute__((target("avx512f,avx512bw,avx512vbmi,bmi2,popcnt"))) void FillRgbRow(uchar* colour, const uchar* bits,
                                                                                   int cols, const uchar* fill) {
  alignas(64) uint8_t pattern[64] = {};
  for (int j = 0; j < 48; ++j) pattern[j] = fill[j % 3];
  const __m512i f = _mm512_load_si512(pattern);
  const std::array<uint8_t, 256>& reversed = Reversed();
  int x = 0;
  for (; x + 16 <= cols; x += 16) {
    const uint32_t empty = ~(uint32_t(reversed[bits[x / 8]]) | uint32_t(reversed[bits[x / 8 + 1]]) << 8) & 0xFFFF;
    if (!empty) continue;
    const uint64_t first = _pdep_u64(empty, 0x249249249249ull);  // each empty pixel's first byte
    _mm512_mask_storeu_epi8(colour + 3 * x, first | first << 1 | first << 2, f);
  }
  for (; x < cols; ++x)
    if (!((bits[x / 8] >> (7 - x % 8)) & 1))
      for (int c = 0; c < 3; ++c) colour[3 * x + c] = fill[c];
}

void FillRow(uchar* colour, const uchar* bits, int cols, int n, const uchar* fill) {
  for (int x = 0; x < cols; ++x)
    if (!((bits[x / 8] >> (7 - x % 8)) & 1))
      for (int c = 0; c < n; ++c) colour[size_t(x) * size_t(n) + size_t(c)] = fill[c];
}

}  // namespace

void SplitMask(const cv::Mat& tile, cv::Mat* colour, cv::Mat* bits) {
  CV_Assert(tile.depth() == CV_8U && (tile.channels() == 2 || tile.channels() == 4) && tile.cols % 8 == 0);
  const int cn = tile.channels(), n = cn - 1;
  colour->create(tile.size(), CV_8UC(n));
  bits->create(tile.rows, tile.cols / 8, CV_8UC1);
  const bool fast = cn == 4 && CpuHasAvx512Vbmi();
  Sums s;
  for (int y = 0; y < tile.rows; ++y) {
    if (fast) SplitRgbaRow(tile.ptr<uchar>(y), tile.cols, colour->ptr<uchar>(y), bits->ptr<uchar>(y), &s);
    else SplitRowFrom(tile.ptr<uchar>(y), tile.cols, cn, 0, colour->ptr<uchar>(y), bits->ptr<uchar>(y), &s);
  }
  if (s.count == 0 || s.count == tile.total()) return;
  // cv::mean's: the sums times the count's reciprocal, rounded.
  uchar fill[3];
  for (int c = 0; c < n; ++c) fill[c] = cv::saturate_cast<uchar>(double(s.colour[c]) * (1. / double(s.count)));
  for (int y = 0; y < tile.rows; ++y) {
    if (fast) FillRgbRow(colour->ptr<uchar>(y), bits->ptr<uchar>(y), tile.cols, fill);
    else FillRow(colour->ptr<uchar>(y), bits->ptr<uchar>(y), tile.cols, n, fill);
  }
}

}  // namespace rolamos
