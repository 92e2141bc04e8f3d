#include "engine/channel_shuffle.h"

#include <immintrin.h>

#include <array>
#include <cstdint>

#include <opencv2/core.hpp>

#include "rolamos/error.hpp"
#include "util/cpu_features.h"

namespace rolamos {
namespace {

// Byte indices into the pair of vectors (a, b) = bytes 0..127 of 64 BGR pixels, then into
// (first step's result, c): channel k's 64 bytes, pixel order.
struct SplitOrder {
  std::array<std::array<uint8_t, 64>, 3> first, second;
  SplitOrder() {
    for (int k = 0; k < 3; ++k)
      for (int p = 0; p < 64; ++p) {
        const int at = 3 * p + k;  // byte of the 192
        // Pixels whose byte is in a or b come from the first permute, kept in place by the second.
        first[size_t(k)][size_t(p)] = static_cast<uint8_t>(at < 128 ? at : 0);
        second[size_t(k)][size_t(p)] = static_cast<uint8_t>(at < 128 ? p : 64 + (at - 128));
      }
  }
};

__attribute__((target("avx512f,avx512bw,avx512vbmi"))) void SplitRow(const uchar* in, int n, uchar* const out[3]) {
  static const SplitOrder order;
  __m512i first[3], second[3];
  for (int k = 0; k < 3; ++k) {
    first[k] = _mm512_loadu_si512(order.first[size_t(k)].data());
    second[k] = _mm512_loadu_si512(order.second[size_t(k)].data());
  }
  int x = 0;
  for (; x + 64 <= n; x += 64) {
    const __m512i a = _mm512_loadu_si512(in + 3 * x), b = _mm512_loadu_si512(in + 3 * x + 64);
    const __m512i c = _mm512_loadu_si512(in + 3 * x + 128);
    for (int k = 0; k < 3; ++k)
      _mm512_storeu_si512(out[k] + x, _mm512_permutex2var_epi8(_mm512_permutex2var_epi8(a, first[k], b), second[k], c));
  }
  for (; x < n; ++x)
    for (int k = 0; k < 3; ++k) out[k][x] = in[3 * x + k];
}

// Byte indices of 16 BGRW pixels' bytes: colour from the pair of vectors holding BGR bytes
// 48 q .. 48 q + 47 (q = 0..3: which sixteen of the 64 pixels), the fourth from `fourth`.
struct InterleaveOrder {
  std::array<std::array<uint8_t, 64>, 4> colour, code;
  std::array<uint64_t, 4> from_code;  // lanes taken from the code vector
  InterleaveOrder() {
    for (int q = 0; q < 4; ++q) {
      from_code[size_t(q)] = 0;
      const int base = 48 * q < 64 ? 0 : 64;  // the pair is (a, b) for q <= 1, (b, c) after
      for (int p = 0; p < 16; ++p)
        for (int k = 0; k < 4; ++k) {
          const int lane = 4 * p + k;
          if (k < 3) {
            colour[size_t(q)][size_t(lane)] = static_cast<uint8_t>(3 * (16 * q + p) + k - base);
            code[size_t(q)][size_t(lane)] = 0;
          } else {
            colour[size_t(q)][size_t(lane)] = 0;
            code[size_t(q)][size_t(lane)] = static_cast<uint8_t>(16 * q + p);
            from_code[size_t(q)] |= uint64_t(1) << lane;
          }
        }
    }
  }
};

__attribute__((target("avx512f,avx512bw,avx512vbmi"))) void InterleaveRow(const uchar* bgr, const uchar* fourth, int n,
                                                                          uchar* out) {
  static const InterleaveOrder order;
  __m512i colour[4], code[4];
  for (int q = 0; q < 4; ++q) {
    colour[q] = _mm512_loadu_si512(order.colour[size_t(q)].data());
    code[q] = _mm512_loadu_si512(order.code[size_t(q)].data());
  }
  int x = 0;
  for (; x + 64 <= n; x += 64) {
    const __m512i a = _mm512_loadu_si512(bgr + 3 * x), b = _mm512_loadu_si512(bgr + 3 * x + 64);
    const __m512i c = _mm512_loadu_si512(bgr + 3 * x + 128), w = _mm512_loadu_si512(fourth + x);
    for (int q = 0; q < 4; ++q) {
      const __m512i rgb =
          q <= 1 ? _mm512_permutex2var_epi8(a, colour[q], b) : _mm512_permutex2var_epi8(b, colour[q], c);
      _mm512_storeu_si512(out + 4 * x + 64 * q,
                          _mm512_mask_permutexvar_epi8(rgb, order.from_code[size_t(q)], code[q], w));
    }
  }
  for (; x < n; ++x) {
    out[4 * x] = bgr[3 * x];
    out[4 * x + 1] = bgr[3 * x + 1];
    out[4 * x + 2] = bgr[3 * x + 2];
    out[4 * x + 3] = fourth[x];
  }
}

}  // namespace

void SplitBgr(const cv::Mat& bgr, cv::Mat planes[3]) {
  if (bgr.type() != CV_8UC3) Fail("channel split", "image type " + cv::typeToString(bgr.type()) + " is not 8-bit BGR");
  for (int k = 0; k < 3; ++k) planes[k].create(bgr.size(), CV_8U);
  if (!CpuHasAvx512Vbmi()) {
    cv::split(bgr, planes);
    return;
  }
  for (int y = 0; y < bgr.rows; ++y) {
    uchar* const out[3] = {planes[0].ptr(y), planes[1].ptr(y), planes[2].ptr(y)};
    SplitRow(bgr.ptr(y), bgr.cols, out);
  }
}

cv::Mat InterleaveBgrAnd(const cv::Mat& bgr, const cv::Mat& fourth) {
  if (bgr.type() != CV_8UC3 || fourth.type() != CV_8UC1 || fourth.size() != bgr.size())
    Fail("channel interleave", "images of type " + cv::typeToString(bgr.type()) + " and " +
                                   cv::typeToString(fourth.type()) + " are not 8-bit BGR and one channel of its size");
  cv::Mat out(bgr.size(), CV_8UC4);
  if (!CpuHasAvx512Vbmi()) {
    const cv::Mat in[] = {bgr, fourth};
    const int from_to[] = {0, 0, 1, 1, 2, 2, 3, 3};
    cv::mixChannels(in, 2, &out, 1, from_to, 4);
    return out;
  }
  for (int y = 0; y < bgr.rows; ++y) InterleaveRow(bgr.ptr(y), fourth.ptr(y), bgr.cols, out.ptr(y));
  return out;
}

}  // namespace rolamos
