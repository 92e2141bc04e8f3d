#include "engine/sift_descriptor.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <tuple>

#include <immintrin.h>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/sift_math.h"
#include "engine/sift_pyramid.h"
#include "rolamos/error.hpp"

namespace rolamos {
namespace {

constexpr int kWidth = 4;  // the descriptor's grid of histograms, each way
constexpr int kBins = 8;   // orientation bins of each histogram
constexpr int kRow = kWidth + 2;
// Histograms with a border cell each way and two wrap bins, each cell's bins in one vector.
constexpr int kCells = kRow * kRow;


// h[0] += p[0], h[1] += p[1], as one 64-bit addition.
__attribute__((target("avx512f"))) inline void AddPair(float* h, const float* p) {
  const __m128 sum = _mm_add_ps(_mm_castpd_ps(_mm_load_sd(reinterpret_cast<const double*>(h))),
                                _mm_castpd_ps(_mm_load_sd(reinterpret_cast<const double*>(p))));
  _mm_store_sd(reinterpret_cast<double*>(h), _mm_castps_pd(sum));
}

// The samples of one vector (lanes in `valid`) added into the histograms, each lane's four cells'
// bin pairs, lane after lane: `pairs` and `at` as DescribeOne lays them out.
__attribute__((target("avx512f"))) inline void AddSamples(float* base, const float (&pairs)[4][2][16],
                                                           const int32_t* at, unsigned valid) {
  for (unsigned m = valid; m; m &= m - 1) {
    const int l = __builtin_ctz(m);
    const int half_index = (l >> 1) & 1, slot = (l >> 2) * 4 + (l & 1) * 2;
    float* h = base + at[l];
    // Cells (r, c), (r, c + 1), (r + 1, c), (r + 1, c + 1).
    AddPair(h, pairs[0][half_index] + slot);
    AddPair(h + 16, pairs[1][half_index] + slot);
    AddPair(h + 16 * kRow, pairs[2][half_index] + slot);
    AddPair(h + 16 * kRow + 16, pairs[3][half_index] + slot);
  }
}

// The columns j of window row i whose samples can land in the grid: the rotated coordinates
// j cos - i sin and j sin + i cos (in histogram widths) each within (-2.5, 2.5). Widened by a
// column each way; the bins of each sample are still checked exactly. Returns false for none.
// A row's vectors then start at its first such column: a sixth fewer vectors than starting
// each at the window's edge, with the same samples added in the same order.
bool GridColumns(int i, float cos_t, float sin_t, int* first, int* last) {
  double lo = -1e9, hi = 1e9;
  const auto within = [&](double a, double b) {  // a j + b in (-2.5, 2.5)
    if (std::abs(a) < 1e-9) {
      if (std::abs(b) >= 2.5 + 1e-6) lo = 1, hi = 0;
      return;
    }
    const double x = (-2.5 - b) / a, y = (2.5 - b) / a;
    lo = std::max(lo, std::min(x, y));
    hi = std::min(hi, std::max(x, y));
  };
  within(cos_t, -double(i) * sin_t);
  within(sin_t, double(i) * cos_t);
  if (!(lo <= hi)) return false;
  *first = static_cast<int>(std::floor(lo)) - 1;
  *last = static_cast<int>(std::ceil(hi)) + 1;
  return true;
}

// The histograms as OpenCV finishes them: the orientation bins wrapped, the border cells dropped,
// clipped at 0.2 of the norm, scaled to 512 over the norm and rounded to 0..255 (compiled for the
// same instructions as DescribeOne, where it was: the same fused sums, the same values).
__attribute__((target("avx512f,fma"))) void Finish(float (&hist)[kCells][16], float* dst) {
  // The orientation bins wrap; the border cells are dropped.
  float raw[kWidth * kWidth * kBins];
  for (int i = 0; i < kWidth; ++i)
    for (int j = 0; j < kWidth; ++j) {
      float* h = hist[(i + 1) * kRow + (j + 1)];
      h[0] += h[kBins];
      h[1] += h[kBins + 1];
      for (int k = 0; k < kBins; ++k) raw[(i * kWidth + j) * kBins + k] = h[k];
    }
  constexpr int kLen = kWidth * kWidth * kBins;
  float norm2 = 0;
  for (int k = 0; k < kLen; ++k) norm2 += raw[k] * raw[k];
  const float clip = std::sqrt(norm2) * 0.2f;
  norm2 = 0;
  for (int k = 0; k < kLen; ++k) {
    raw[k] = std::min(raw[k], clip);
    norm2 += raw[k] * raw[k];
  }
  const float scale = 512.f / std::max(std::sqrt(norm2), FLT_EPSILON);
  for (int k = 0; k < kLen; ++k) dst[k] = static_cast<float>(cv::saturate_cast<uchar>(raw[k] * scale));
}

// One keypoint's descriptor (OpenCV's calcSIFTDescriptor): `img` its octave layer, `ptf` its
// position there, `ori` its orientation (degrees, clockwise as OpenCV measures it), `scl` its
// scale in the layer's pixels. Writes 128 floats.
__attribute__((target("avx512f,fma"))) void DescribeOne(const cv::Mat& img, cv::Point2f ptf, float ori, float scl,
                                                         std::vector<float>& factors, float* dst) {
  const cv::Point pt(cvRound(ptf.x), cvRound(ptf.y));
  float cos_t = std::cos(ori * float(CV_PI / 180)), sin_t = std::sin(ori * float(CV_PI / 180));
  const float bins_per_degree = kBins / 360.f;
  const float hist_width = 3.f * scl;
  int radius = cvRound(hist_width * 1.4142135623730951f * (kWidth + 1) * 0.5f);
  radius = std::min(radius, static_cast<int>(std::sqrt(double(img.cols) * img.cols + double(img.rows) * img.rows)));
  cos_t /= hist_width;
  sin_t /= hist_width;
  // exp(-(i^2 + j^2) / (2 (d/2)^2)) in histogram widths.
  GaussianFactors(radius, -1.f / (kWidth * kWidth * 0.5f) / (hist_width * hist_width), &factors);
  alignas(64) float hist[kCells][16] = {};
  // Each vector's samples are added one vector late, from the other of two buffers: read right
  // after the vector stores that wrote them, they waited on those stores (a third of the time).
  // The order of the additions is the same.
  alignas(64) float pairs[2][4][2][16];
  alignas(64) int32_t at[2][16];
  unsigned pending = 0;
  int cur = 0;
  const __m512 lanes = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512 vcos = _mm512_set1_ps(cos_t), vsin = _mm512_set1_ps(sin_t);
  const __m512 low = _mm512_set1_ps(-1.f), high = _mm512_set1_ps(float(kWidth));
  const __m512 half_grid = _mm512_set1_ps(float(kWidth / 2)), half = _mm512_set1_ps(0.5f);
  const __m512 vori = _mm512_set1_ps(ori), vbins = _mm512_set1_ps(bins_per_degree);
  const __m512i n = _mm512_set1_epi32(kBins), zero_i = _mm512_setzero_si512();
  const __m512i row_cells = _mm512_set1_epi32(kRow), one_i = _mm512_set1_epi32(1);
  // Columns whose three taps lie inside the image.
  const int j_first = std::max(-radius, 1 - pt.x), j_last = std::min(radius, img.cols - 2 - pt.x);
  for (int i = -radius; i <= radius; ++i) {
    const int r = pt.y + i;
    if (r <= 0 || r >= img.rows - 1 || j_first > j_last) continue;
    PrefetchRow(img, r + 1 + kPrefetchRows, pt.x + j_first - 1, pt.x + j_last + 1);
    int row_first, row_last;
    if (!GridColumns(i, cos_t, sin_t, &row_first, &row_last)) continue;
    row_first = std::max(row_first, j_first);
    row_last = std::min(row_last, j_last);
    const __m512 isin = _mm512_set1_ps(float(i) * sin_t), icos = _mm512_set1_ps(float(i) * cos_t);
    const __m512 row_weight = _mm512_set1_ps(factors[size_t(i + radius)]);
    for (int j0 = row_first; j0 <= row_last; j0 += 16) {
      const __m512 j = _mm512_add_ps(_mm512_set1_ps(float(j0)), lanes);
      const __m512 c_rot = _mm512_sub_ps(_mm512_mul_ps(j, vcos), isin);
      const __m512 r_rot = _mm512_add_ps(_mm512_mul_ps(j, vsin), icos);
      __m512 rbin = _mm512_sub_ps(_mm512_add_ps(r_rot, half_grid), half);
      __m512 cbin = _mm512_sub_ps(_mm512_add_ps(c_rot, half_grid), half);
      __mmask16 valid = _mm512_cmp_ps_mask(rbin, low, _CMP_GT_OQ) & _mm512_cmp_ps_mask(rbin, high, _CMP_LT_OQ) &
                        _mm512_cmp_ps_mask(cbin, low, _CMP_GT_OQ) & _mm512_cmp_ps_mask(cbin, high, _CMP_LT_OQ);
      if (j_last - j0 < 15) valid &= static_cast<__mmask16>((1u << (j_last - j0 + 1)) - 1);
      if (!valid) continue;
      __m512 dx, dy;
      Gradients(img, r, pt.x + j0, valid, &dx, &dy);
      const __m512 weight = _mm512_mul_ps(row_weight, _mm512_loadu_ps(factors.data() + (j0 + radius)));
      const __m512 mag = _mm512_mul_ps(_mm512_sqrt_ps(_mm512_fmadd_ps(dx, dx, _mm512_mul_ps(dy, dy))), weight);
      __m512 obin = _mm512_mul_ps(_mm512_sub_ps(Atan2Degrees(dy, dx), vori), vbins);
      const __m512 fr = _mm512_roundscale_ps(rbin, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      const __m512 fc = _mm512_roundscale_ps(cbin, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      const __m512 fo = _mm512_roundscale_ps(obin, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      rbin = _mm512_sub_ps(rbin, fr);
      cbin = _mm512_sub_ps(cbin, fc);
      obin = _mm512_sub_ps(obin, fo);
      __m512i o0 = _mm512_cvttps_epi32(fo);
      o0 = _mm512_mask_add_epi32(o0, _mm512_cmplt_epi32_mask(o0, zero_i), o0, n);
      o0 = _mm512_mask_sub_epi32(o0, _mm512_cmpge_epi32_mask(o0, n), o0, n);
      const __m512i cell = _mm512_add_epi32(_mm512_mullo_epi32(_mm512_add_epi32(_mm512_cvttps_epi32(fr), one_i), row_cells),
                                            _mm512_add_epi32(_mm512_cvttps_epi32(fc), one_i));
      // The trilinear split, as OpenCV computes it.
      const __m512 r1 = _mm512_mul_ps(mag, rbin), r0 = _mm512_sub_ps(mag, r1);
      const __m512 rc11 = _mm512_mul_ps(r1, cbin), rc10 = _mm512_sub_ps(r1, rc11);
      const __m512 rc01 = _mm512_mul_ps(r0, cbin), rc00 = _mm512_sub_ps(r0, rc01);
      // Each cell's two bins (o0, o0 + 1) as a pair, OpenCV's (w - w o, w o): lane l's pair of
      // cell q at pairs[q][l & 2 ? 1 : 0][(l >> 2) * 4 + (l & 1) * 2].
      const __m512 part[4] = {rc00, rc01, rc10, rc11};
      for (int q = 0; q < 4; ++q) {
        const __m512 upper = _mm512_mul_ps(part[q], obin), lower = _mm512_sub_ps(part[q], upper);
        _mm512_store_ps(pairs[cur][q][0], _mm512_unpacklo_ps(lower, upper));
        _mm512_store_ps(pairs[cur][q][1], _mm512_unpackhi_ps(lower, upper));
      }
      _mm512_store_si512(at[cur], _mm512_add_epi32(_mm512_slli_epi32(cell, 4), o0));
      AddSamples(&hist[0][0], pairs[cur ^ 1], at[cur ^ 1], pending);
      pending = valid;
      cur ^= 1;
    }
  }
  AddSamples(&hist[0][0], pairs[cur ^ 1], at[cur ^ 1], pending);
  Finish(hist, dst);
}

}  // namespace

void DescribeSift(const cv::Mat& image, const std::vector<cv::KeyPoint>& keypoints, int layers, double sigma,
                  cv::Mat* descriptors) {
  if (image.type() != CV_8UC1) Fail("SIFT descriptors", "image type " + cv::typeToString(image.type()) + " is not 8-bit grey");
  if (!FastSiftApplies()) {
    std::vector<cv::KeyPoint> copy = keypoints;
    cv::SIFT::create(0, layers, 0.04, 10, sigma)->compute(image, copy, *descriptors);
    return;
  }
  descriptors->create(static_cast<int>(keypoints.size()), kWidth * kWidth * kBins, CV_32F);
  if (keypoints.empty()) return;
  int first = 0, last = INT_MIN, top = 0;
  for (const auto& k : keypoints) {
    int octave, layer;
    float scale;
    UnpackSiftOctave(k, &octave, &layer, &scale);
    first = std::min(first, octave);
    last = std::max(last, octave);
    top = std::max(top, layer);
  }
  if (first < -1 || top > layers + 2)
    Fail("SIFT descriptors", "a keypoint's octave (" + std::to_string(first) + ") or layer (" + std::to_string(top) +
                                 ") is not one SIFT with " + std::to_string(layers) + " layers finds");
  const cv::Mat base = SiftBaseImage(image, first < 0, static_cast<float>(sigma));
  DescribeSiftOn(SiftGaussianPyramid(base, last - first + 1, layers, top, sigma), first, keypoints, descriptors);
}

void DescribeSiftOn(const std::vector<std::vector<cv::Mat>>& pyramid, int first_octave,
                    const std::vector<cv::KeyPoint>& keypoints, cv::Mat* descriptors) {
  CV_Assert(FastSiftApplies());
  descriptors->create(static_cast<int>(keypoints.size()), kWidth * kWidth * kBins, CV_32F);
  // Keypoints in the order of their layers' rows: the windows of one overlap the next's, in cache.
  std::vector<int> order(keypoints.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    const cv::KeyPoint &p = keypoints[size_t(a)], &q = keypoints[size_t(b)];
    return std::make_tuple(p.octave & 0xFFFF, p.pt.y, p.pt.x) < std::make_tuple(q.octave & 0xFFFF, q.pt.y, q.pt.x);
  });
  cv::parallel_for_(cv::Range(0, static_cast<int>(keypoints.size())), [&](const cv::Range& range) {
    std::vector<float> factors;
    for (int n = range.start; n < range.end; ++n) {
      const int i = order[size_t(n)];
      const cv::KeyPoint& k = keypoints[size_t(i)];
      int octave, layer;
      float scale;
      UnpackSiftOctave(k, &octave, &layer, &scale);
      const cv::Mat& img = pyramid[size_t(octave - first_octave)][size_t(layer)];
      float angle = 360.f - k.angle;
      if (std::abs(angle - 360.f) < FLT_EPSILON) angle = 0.f;
      DescribeOne(img, cv::Point2f(k.pt.x * scale, k.pt.y * scale), angle, k.size * scale * 0.5f, factors,
                  descriptors->ptr<float>(i));
    }
  });
}

}  // namespace rolamos
