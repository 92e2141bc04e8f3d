#include "engine/bilateral_filter.h"

#include <immintrin.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

constexpr int kTable = 64;  // colour weights held in registers: differences 0..63 (63 and up: 0)

// OpenCV's neighbourhood: the offsets within the radius, row by row, and their space weights.
struct Neighbourhood {
  std::vector<std::ptrdiff_t> offset;  // in a plane of `step` bytes a row
  std::vector<float> weight;
};

Neighbourhood MakeNeighbourhood(int radius, double sigma_space, size_t step) {
  const double coeff = -0.5 / (sigma_space * sigma_space);
  Neighbourhood n;
  for (int i = -radius; i <= radius; ++i)
    for (int j = -radius; j <= radius; ++j) {
      const double r = std::sqrt(double(i) * i + double(j) * j);
      if (r > radius) continue;
      n.offset.push_back(std::ptrdiff_t(i) * std::ptrdiff_t(step) + j);
      n.weight.push_back(static_cast<float>(std::exp(r * r * coeff)));
    }
  return n;
}

// One pixel, as OpenCV sums it: the neighbours in order, weight = space x colour.
inline void FilterPixel(const uchar* const planes[3], int x, const Neighbourhood& n, const float* table, uchar* out) {
  const int b0 = planes[0][x], g0 = planes[1][x], r0 = planes[2][x];
  float sb = 0, sg = 0, sr = 0, ws = 0;
  for (size_t k = 0; k < n.offset.size(); ++k) {
    const std::ptrdiff_t at = n.offset[k] + x;
    const int b = planes[0][at], g = planes[1][at], r = planes[2][at];
    const int d = std::min(kTable - 1, std::abs(b - b0) + std::abs(g - g0) + std::abs(r - r0));
    const float w = table[d] * n.weight[k];
    ws += w;
    sb += w * float(b);
    sg += w * float(g);
    sr += w * float(r);
  }
  const float inv = 1.f / ws;
  out[0] = static_cast<uchar>(cvRound(sb * inv));
  out[1] = static_cast<uchar>(cvRound(sg * inv));
  out[2] = static_cast<uchar>(cvRound(sr * inv));
}

__attribute__((target("avx512f"))) inline __m512i Load16(const uchar* p) {
  return _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
}

// Rows [y0, y1) of `dst` from the padded planes, sixteen pixels at a time.
__attribute__((target("avx512f"))) void FilterRows(const cv::Mat* planes, int radius, const Neighbourhood& n,
                                                   const float* table, cv::Mat& dst, int y0, int y1) {
  const __m512 t0 = _mm512_loadu_ps(table), t1 = _mm512_loadu_ps(table + 16);
  const __m512 t2 = _mm512_loadu_ps(table + 32), t3 = _mm512_loadu_ps(table + 48);
  const __m512i last = _mm512_set1_epi32(kTable - 1), upper = _mm512_set1_epi32(32);
  const int width = dst.cols;
  const size_t taps = n.offset.size();
  for (int y = y0; y < y1; ++y) {
    const uchar* const p[3] = {planes[0].ptr(y + radius) + radius, planes[1].ptr(y + radius) + radius,
                               planes[2].ptr(y + radius) + radius};
    uchar* out = dst.ptr(y);
    int x = 0;
    for (; x + 16 <= width; x += 16) {
      const __m512i b0 = Load16(p[0] + x), g0 = Load16(p[1] + x), r0 = Load16(p[2] + x);
      __m512 sb = _mm512_setzero_ps(), sg = sb, sr = sb, ws = sb;
      for (size_t k = 0; k < taps; ++k) {
        const std::ptrdiff_t at = n.offset[k] + x;
        const __m512i b = Load16(p[0] + at), g = Load16(p[1] + at), r = Load16(p[2] + at);
        __m512i d = _mm512_add_epi32(_mm512_add_epi32(_mm512_abs_epi32(_mm512_sub_epi32(b, b0)),
                                                      _mm512_abs_epi32(_mm512_sub_epi32(g, g0))),
                                     _mm512_abs_epi32(_mm512_sub_epi32(r, r0)));
        d = _mm512_min_epi32(d, last);
        // Entries 0..31 from t0:t1, 32..63 from t2:t3 (the permute reads the index's low 5 bits).
        const __m512 colour = _mm512_mask_blend_ps(_mm512_cmpge_epi32_mask(d, upper), _mm512_permutex2var_ps(t0, d, t1),
                                                   _mm512_permutex2var_ps(t2, d, t3));
        const __m512 w = _mm512_mul_ps(colour, _mm512_set1_ps(n.weight[k]));
        ws = _mm512_add_ps(ws, w);
        sb = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(b), sb);
        sg = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(g), sg);
        sr = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(r), sr);
      }
      const __m512 inv = _mm512_div_ps(_mm512_set1_ps(1.f), ws);
      alignas(64) std::int32_t vb[16], vg[16], vr[16];
      _mm512_store_si512(vb, _mm512_cvtps_epi32(_mm512_mul_ps(sb, inv)));
      _mm512_store_si512(vg, _mm512_cvtps_epi32(_mm512_mul_ps(sg, inv)));
      _mm512_store_si512(vr, _mm512_cvtps_epi32(_mm512_mul_ps(sr, inv)));
      uchar* o = out + 3 * x;
      for (int i = 0; i < 16; ++i, o += 3) {
        o[0] = static_cast<uchar>(vb[i]);
        o[1] = static_cast<uchar>(vg[i]);
        o[2] = static_cast<uchar>(vr[i]);
      }
    }
    for (; x < width; ++x) FilterPixel(p, x, n, table, out + 3 * x);
  }
}

}  // namespace

bool FastBilateralApplies(const cv::Mat& src, double sigma_color) {
  return src.type() == CV_8UC3 && !src.empty() && sigma_color > 0 && sigma_color <= kFastBilateralMaxSigmaColor &&
         CpuHasAvx512();
}

void BilateralFilter(const cv::Mat& src, cv::Mat& dst, int diameter, double sigma_color, double sigma_space) {
  if (!FastBilateralApplies(src, sigma_color)) {
    cv::bilateralFilter(src, dst, diameter, sigma_color, sigma_space);
    return;
  }
  // OpenCV's reading of the arguments.
  if (sigma_space <= 0) sigma_space = 1;
  const int radius = std::max(1, diameter <= 0 ? cvRound(sigma_space * 1.5) : diameter / 2);
  const double colour_coeff = -0.5 / (sigma_color * sigma_color);
  std::array<float, kTable> table{};
  for (int i = 0; i < kTable - 1; ++i) table[size_t(i)] = static_cast<float>(std::exp(i * i * colour_coeff));
  cv::Mat padded;
  cv::copyMakeBorder(src, padded, radius, radius, radius, radius, cv::BORDER_REFLECT_101);
  cv::Mat planes[3];
  cv::split(padded, planes);
  const Neighbourhood n = MakeNeighbourhood(radius, sigma_space, planes[0].step);
  cv::Mat out(src.size(), CV_8UC3);  // not dst: src may be dst
  cv::parallel_for_(cv::Range(0, src.rows), [&](const cv::Range& rows) {
    FilterRows(planes, radius, n, table.data(), out, rows.start, rows.end);
  });
  dst = out;
}

}  // namespace rolamos
