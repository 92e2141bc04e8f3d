#include "engine/grey.h"

#include <cstdint>

#include <immintrin.h>
#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

// OpenCV 4's weights for 8-bit grey, in 15 bits (its vector and its table paths alike).
constexpr int kShift = 15;
constexpr int kB = 3735, kG = 19235, kR = 9798;  // sum 32768

int GreyOf(const uchar* p) { return (p[0] * kB + p[1] * kG + p[2] * kR + (1 << (kShift - 1))) >> kShift; }

// The byte indices that spread 16 pixels' 48 bytes into 32-bit lanes of two int16 each: (blue,
// green), and (red, 1) where 64 and 65 pick the bytes 0 and 1 of the second source.
struct Spread {
  alignas(64) uint8_t blue_green[64];
  alignas(64) uint8_t red_one[64];
  Spread() {
    for (int i = 0; i < 16; ++i) {
      const uint8_t lane[2][4] = {{uint8_t(3 * i), 64, uint8_t(3 * i + 1), 64}, {uint8_t(3 * i + 2), 64, 65, 64}};
      for (int k = 0; k < 4; ++k) blue_green[4 * i + k] = lane[0][k], red_one[4 * i + k] = lane[1][k];
    }
  }
};

// One row, sixteen pixels a vector: (b, g) . (kB, kG) + (r, 1) . (kR, 2^14), then >> 15.
__attribute__((target("avx512f,avx512bw,avx512vbmi"))) void RowWide(const uchar* in, int cols, uchar* out) {
  static const Spread spread;
  const __m512i bg = _mm512_load_si512(spread.blue_green), r1 = _mm512_load_si512(spread.red_one);
  const __m512i bytes01 = _mm512_set1_epi16(0x0100);  // byte 0: 0, byte 1: 1
  const __m512i w_bg = _mm512_set1_epi32(kB | (kG << 16));
  const __m512i w_r1 = _mm512_set1_epi32(kR | ((1 << (kShift - 1)) << 16));
  int x = 0;
  for (; x + 16 <= cols; x += 16) {
    const __m512i v = _mm512_maskz_loadu_epi8(0xFFFFFFFFFFFFull, in + 3 * x);  // 48 bytes
    const __m512i sum = _mm512_add_epi32(_mm512_madd_epi16(_mm512_permutex2var_epi8(v, bg, bytes01), w_bg),
                                         _mm512_madd_epi16(_mm512_permutex2var_epi8(v, r1, bytes01), w_r1));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm512_cvtepi32_epi8(_mm512_srli_epi32(sum, kShift)));
  }
  for (; x < cols; ++x) out[x] = uchar(GreyOf(in + 3 * x));
}

}  // namespace

void BgrToGrey(const cv::Mat& bgr, cv::Mat& grey) {
  if (bgr.type() != CV_8UC3 || !CpuHasAvx512Vbmi()) {
    if (bgr.channels() == 3) cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
    else if (bgr.channels() == 4) cv::cvtColor(bgr, grey, cv::COLOR_BGRA2GRAY);
    else bgr.copyTo(grey);
    return;
  }
  cv::Mat out(bgr.size(), CV_8UC1);
  cv::parallel_for_(cv::Range(0, bgr.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) RowWide(bgr.ptr<uchar>(y), bgr.cols, out.ptr<uchar>(y));
  }, double(bgr.total()) / double(1 << 16));
  grey = out;
}

}  // namespace rolamos
