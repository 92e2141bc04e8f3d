#include "engine/bilateral_filter.h"

#include <immintrin.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/channel_shuffle.h"
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

__attribute__((target("avx512f"))) inline __m512i Load16(const uchar* p) {
  return _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
}

// The first `count` of sixteen pixels' sums over their weights, rounded, as BGR bytes.
__attribute__((target("avx512f"))) inline void StoreSixteen(__m512 sb, __m512 sg, __m512 sr, __m512 ws, int count,
                                                           uchar* o) {
  const __m512 inv = _mm512_div_ps(_mm512_set1_ps(1.f), ws);
  alignas(64) std::int32_t vb[16], vg[16], vr[16];
  _mm512_store_si512(vb, _mm512_cvtps_epi32(_mm512_mul_ps(sb, inv)));
  _mm512_store_si512(vg, _mm512_cvtps_epi32(_mm512_mul_ps(sg, inv)));
  _mm512_store_si512(vr, _mm512_cvtps_epi32(_mm512_mul_ps(sr, inv)));
  for (int i = 0; i < count; ++i, o += 3) {
    o[0] = static_cast<uchar>(vb[i]);
    o[1] = static_cast<uchar>(vg[i]);
    o[2] = static_cast<uchar>(vr[i]);
  }
}

// Pixels x .. x + count - 1 (count <= 16) of a row, as OpenCV sums them: the neighbours in
// order, weight = colour x space. Fused: each value multiplied in and added by one multiply-add
// (the vector steps); else the product rounded, then added (what the scalar tail did, which the
// last width % 16 pixels of a row keep). `p` are the padded planes at the row, readable 16
// bytes past each row's last neighbour (PaddedPlanes' slack): lanes past `count` are not written.
template <bool kFused>
__attribute__((target("avx512f"))) void FilterSixteen(const uchar* const p[3], int x, int count, const Neighbourhood& n,
                                                      const float* table, uchar* out) {
  const __m512 t0 = _mm512_loadu_ps(table), t1 = _mm512_loadu_ps(table + 16);
  const __m512 t2 = _mm512_loadu_ps(table + 32), t3 = _mm512_loadu_ps(table + 48);
  const __m512i last = _mm512_set1_epi32(kTable - 1), upper = _mm512_set1_epi32(32);
  const __m512i b0 = Load16(p[0] + x), g0 = Load16(p[1] + x), r0 = Load16(p[2] + x);
  __m512 sb = _mm512_setzero_ps(), sg = sb, sr = sb, ws = sb;
  for (size_t k = 0; k < n.offset.size(); ++k) {
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
    if (kFused) {
      sb = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(b), sb);
      sg = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(g), sg);
      sr = _mm512_fmadd_ps(w, _mm512_cvtepi32_ps(r), sr);
    } else {
      sb = _mm512_add_ps(sb, _mm512_mul_ps(w, _mm512_cvtepi32_ps(b)));
      sg = _mm512_add_ps(sg, _mm512_mul_ps(w, _mm512_cvtepi32_ps(g)));
      sr = _mm512_add_ps(sr, _mm512_mul_ps(w, _mm512_cvtepi32_ps(r)));
    }
  }
  StoreSixteen(sb, sg, sr, ws, count, out + 3 * x);
}

// Columns [x0, x1) of rows [y0, y1) of `dst` from the padded planes: sixteen pixels at a time,
// then the row's tail.
__attribute__((target("avx512f"))) void FilterRows(const cv::Mat* planes, int radius, const Neighbourhood& n,
                                                   const float* table, cv::Mat& dst, int y0, int y1, int x0, int x1) {
  for (int y = y0; y < y1; ++y) {
    const uchar* const p[3] = {planes[0].ptr(y + radius) + radius, planes[1].ptr(y + radius) + radius,
                               planes[2].ptr(y + radius) + radius};
    int x = x0;
    for (; x + 16 <= x1; x += 16) FilterSixteen<true>(p, x, 16, n, table, dst.ptr(y));
    if (x < x1) FilterSixteen<false>(p, x, x1 - x, n, table, dst.ptr(y));
  }
}

// The 32-pixel step of FilterRows32: with AVX-512 BW, a pixel's colour difference is summed in
// 16 bits, 32 pixels to a vector, and its weight read from a table as two 16-bit halves (each a
// permute over 64 entries, no blend), then widened. Each neighbour has its own table of colour x
// space weights (the same float products as the 16-pixel step's). Each pixel's weights and sums
// are the 16-pixel step's, in its order: the same bits. (The neighbours' values read as floats
// from float planes were slower than widened from 16 bytes: a 64-byte load mostly splits across
// cache lines.)
struct Wide {
  // Per neighbour, the table's floats' upper and lower 16 bits: entries 0..31, then 32..63.
  std::vector<std::array<uint16_t, 2 * kTable>> halves;
  // Puts pixel 4L + j at word 8L + j and 16 + 4L + j at 8L + 4 + j: unpacklo/hi_epi16 pair the
  // words 0..3 / 4..7 of each 128-bit lane L into dwords 4L..4L+3, pixels 0..15 and 16..31.
  alignas(64) std::array<uint16_t, 32> order;
};

Wide MakeWide(const float* table, const Neighbourhood& n) {
  Wide w;
  w.halves.resize(n.weight.size());
  for (size_t k = 0; k < n.weight.size(); ++k)
    for (int i = 0; i < kTable; ++i) {
      const float product = table[i] * n.weight[k];
      uint32_t bits;
      std::memcpy(&bits, &product, 4);
      w.halves[k][size_t(i)] = static_cast<uint16_t>(bits >> 16);
      w.halves[k][size_t(kTable + i)] = static_cast<uint16_t>(bits & 0xFFFF);
    }
  for (int lane = 0; lane < 4; ++lane)
    for (int j = 0; j < 4; ++j) {
      w.order[size_t(8 * lane + j)] = static_cast<uint16_t>(4 * lane + j);
      w.order[size_t(8 * lane + 4 + j)] = static_cast<uint16_t>(16 + 4 * lane + j);
    }
  return w;
}

__attribute__((target("avx512f,avx512bw"))) inline __m512i Load32(const uchar* p) {
  return _mm512_cvtepu8_epi16(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)));
}

// Pixels x .. x + 31 of a row (`p`: the padded planes at the row).
__attribute__((target("avx512f,avx512bw"))) inline void Filter32(const uchar* const p[3], int x,
                                                                   const Neighbourhood& n, const Wide& t, uchar* out) {
  const __m512i b0 = Load32(p[0] + x), g0 = Load32(p[1] + x), r0 = Load32(p[2] + x);
  const __m512i last = _mm512_set1_epi16(kTable - 1), order = _mm512_load_si512(t.order.data());
  __m512 sb[2], sg[2], sr[2], ws[2];
  for (int h = 0; h < 2; ++h) sb[h] = sg[h] = sr[h] = ws[h] = _mm512_setzero_ps();
  const size_t taps = n.offset.size();
  for (size_t k = 0; k < taps; ++k) {
    const std::ptrdiff_t at = n.offset[k] + x;
    __m512i d = _mm512_add_epi16(_mm512_add_epi16(_mm512_abs_epi16(_mm512_sub_epi16(Load32(p[0] + at), b0)),
                                                  _mm512_abs_epi16(_mm512_sub_epi16(Load32(p[1] + at), g0))),
                                 _mm512_abs_epi16(_mm512_sub_epi16(Load32(p[2] + at), r0)));
    d = _mm512_permutexvar_epi16(order, _mm512_min_epu16(d, last));
    const uint16_t* half = t.halves[k].data();
    const __m512i high = _mm512_permutex2var_epi16(_mm512_loadu_si512(half), d, _mm512_loadu_si512(half + 32));
    const __m512i low = _mm512_permutex2var_epi16(_mm512_loadu_si512(half + 64), d, _mm512_loadu_si512(half + 96));
    const __m512 w[2] = {_mm512_castsi512_ps(_mm512_unpacklo_epi16(low, high)),
                         _mm512_castsi512_ps(_mm512_unpackhi_epi16(low, high))};
    for (int h = 0; h < 2; ++h) {
      const std::ptrdiff_t q = at + 16 * h;
      ws[h] = _mm512_add_ps(ws[h], w[h]);
      sb[h] = _mm512_fmadd_ps(w[h], _mm512_cvtepi32_ps(Load16(p[0] + q)), sb[h]);
      sg[h] = _mm512_fmadd_ps(w[h], _mm512_cvtepi32_ps(Load16(p[1] + q)), sg[h]);
      sr[h] = _mm512_fmadd_ps(w[h], _mm512_cvtepi32_ps(Load16(p[2] + q)), sr[h]);
    }
  }
  for (int h = 0; h < 2; ++h) StoreSixteen(sb[h], sg[h], sr[h], ws[h], 16, out + 3 * (x + 16 * h));
}

// Rows [y0, y1) with the 32-pixel step (AVX-512 BW), then FilterRows' steps for the rest.
__attribute__((target("avx512f,avx512bw"))) void FilterRows32(const cv::Mat* planes, int radius,
                                                              const Neighbourhood& n, const Wide& t, const float* table,
                                                              cv::Mat& dst, int y0, int y1) {
  const int width = dst.cols, wide_end = width - width % 32;
  for (int y = y0; y < y1; ++y) {
    const uchar* const p[3] = {planes[0].ptr(y + radius) + radius, planes[1].ptr(y + radius) + radius,
                               planes[2].ptr(y + radius) + radius};
    for (int x = 0; x < wide_end; x += 32) Filter32(p, x, n, t, dst.ptr(y));
    FilterRows(planes, radius, n, table, dst, y, y + 1, wide_end, width);
  }
}

// `src` with a border of `radius` reflected (BORDER_REFLECT_101), split into three planes whose
// rows run on `slack` bytes past the border (never read into results).
void PaddedPlanes(const cv::Mat& src, int radius, int slack, cv::Mat planes[3]) {
  const int rows = src.rows + 2 * radius, cols = src.cols + 2 * radius;
  cv::Mat inner[3];
  for (int c = 0; c < 3; ++c) {
    planes[c] = cv::Mat(rows, cols + slack, CV_8U);
    planes[c].colRange(cols, cols + slack).setTo(0);
    inner[c] = planes[c](cv::Rect(radius, radius, src.cols, src.rows));
  }
  SplitBgr(src, inner);  // into the planes (create keeps a view of the right size and type)
  for (int c = 0; c < 3; ++c) {
    CV_Assert(inner[c].data == planes[c].ptr(radius) + radius);
    for (int y = radius; y < radius + src.rows; ++y) {
      uchar* row = planes[c].ptr(y);
      for (int j = 0; j < radius; ++j) {
        row[j] = row[radius + cv::borderInterpolate(j - radius, src.cols, cv::BORDER_REFLECT_101)];
        const int right = cv::borderInterpolate(src.cols + j, src.cols, cv::BORDER_REFLECT_101);
        row[radius + src.cols + j] = row[radius + right];
      }
    }
    for (int j = 0; j < radius; ++j) {
      const int above = cv::borderInterpolate(j - radius, src.rows, cv::BORDER_REFLECT_101);
      const int below = cv::borderInterpolate(src.rows + j, src.rows, cv::BORDER_REFLECT_101);
      planes[c].row(radius + above).copyTo(planes[c].row(j));
      planes[c].row(radius + below).copyTo(planes[c].row(radius + src.rows + j));
    }
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
  cv::Mat planes[3];
  PaddedPlanes(src, radius, 16, planes);
  const Neighbourhood n = MakeNeighbourhood(radius, sigma_space, planes[0].step);
  cv::Mat out(src.size(), CV_8UC3);  // not dst: src may be dst
  if (CpuHasAvx512Bw()) {
    const Wide wide = MakeWide(table.data(), n);
    cv::parallel_for_(cv::Range(0, src.rows), [&](const cv::Range& rows) {
      FilterRows32(planes, radius, n, wide, table.data(), out, rows.start, rows.end);
    });
  } else {
    cv::parallel_for_(cv::Range(0, src.rows), [&](const cv::Range& rows) {
      FilterRows(planes, radius, n, table.data(), out, rows.start, rows.end, 0, src.cols);
    });
  }
  dst = out;
}

}  // namespace rolamos
