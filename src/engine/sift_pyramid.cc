#include "engine/sift_pyramid.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <vector>

#include <immintrin.h>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {

namespace {

constexpr float kInitSigma = 0.5f;  // the blur the input image is assumed to have (OpenCV's)

// The mask of the lanes of a vector at column x that lie before `cols`.
inline __mmask16 LanesBefore(int cols, int x) {
  return cols - x >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (cols - x)) - 1);
}

// N vectors of the row pass (the last one's lanes in `last`): out[i] = sum_k kernel[k] in[i + k],
// each a chain of ksize multiply-adds from k = 0 in OpenCV's order. N chains at once, since one
// at a time waits on the previous multiply-add's latency.
template <int N>
__attribute__((target("avx512f"))) inline void RowVectors(const float* in, const float* kernel, int ksize,
                                                          __mmask16 last, float* out) {
  __m512 s[N];
  for (int v = 0; v < N; ++v) s[v] = _mm512_setzero_ps();
  for (int k = 0; k < ksize; ++k) {
    const __m512 w = _mm512_set1_ps(kernel[k]);
    for (int v = 0; v < N; ++v)
      s[v] = _mm512_fmadd_ps(_mm512_maskz_loadu_ps(v == N - 1 ? last : __mmask16(0xFFFF), in + k + 16 * v), w, s[v]);
  }
  for (int v = 0; v < N; ++v) _mm512_mask_storeu_ps(out + 16 * v, v == N - 1 ? last : __mmask16(0xFFFF), s[v]);
}

// Row y of `src` filtered by `kernel` (ksize taps, borders reflected): out[x] = sum_k
// kernel[k] src[x - r + k], accumulated from k = 0 by fused multiply-adds, as OpenCV's AVX2 row
// filter does it. Vectors whose taps lie inside the row read it where it is; the others read
// `ext`, the row with its reflected border, filled for them alone (copying whole rows into it
// cost a third as much as the filtering).
__attribute__((target("avx512f"))) void BlurRow(const float* row, int cols, const float* kernel, int ksize,
                                                const int* index, float* ext, float* out) {
  const int r = ksize / 2;
  // ext[i] = row[index[i]] (index[i] reflects i - r) for i in [from, to).
  auto fill = [&](int from, int to) {
    for (int i = std::max(from, 0); i < std::min(to, cols + 2 * r); ++i) ext[i] = row[index[i]];
  };
  int x = 0;
  for (; x + 64 <= cols; x += 64) {
    const bool inside = x >= r && x + 64 + r <= cols;
    if (!inside) fill(x, x + 64 + 2 * r);
    RowVectors<4>(inside ? row + (x - r) : ext + x, kernel, ksize, 0xFFFF, out + x);
  }
  for (; x < cols; x += 16) {
    const bool inside = x >= r && x + 16 + r <= cols;
    if (!inside) fill(x, x + 16 + 2 * r);
    RowVectors<1>(inside ? row + (x - r) : ext + x, kernel, ksize, LanesBefore(cols, x), out + x);
  }
}

// The column pass of R output rows at once, N vectors from x (the last one's lanes in `last`):
// rows[i] is the row-filtered row y - r + i (reflected), i < ksize + R - 1; output row y + j is
// the centre times the middle tap, then each pair of rows about it summed and multiplied in, as
// OpenCV's symmetric AVX2 column filter does it. Neighbouring outputs share all but two of their
// rows at each tap, so the rows are read once for the R outputs (the pass waited on the loads
// when each output read its own), and passed down registers: above[j] and below[j] hold output
// j's pair at tap k. With `from` and `difference`, also difference = out - from (the source's
// row): SIFT's difference of Gaussians while the row is in registers, as cv::subtract computes it.
template <int R, int N>
__attribute__((target("avx512f"))) inline void ColumnVectors(const float* const* rows, int x, const float* kernel,
                                                             int r, __mmask16 last, float* const* out,
                                                             const float* const* from, float* const* difference) {
  auto lanes = [last](int v) { return v == N - 1 ? last : __mmask16(0xFFFF); };
  const __m512 c = _mm512_set1_ps(kernel[r]);
  __m512 s[R][N], above[R][N], below[R][N];
  for (int v = 0; v < N; ++v)
    for (int j = 0; j < R; ++j) {
      const __m512 centre = _mm512_maskz_loadu_ps(lanes(v), rows[r + j] + x + 16 * v);
      s[j][v] = _mm512_mul_ps(centre, c);
      // Before tap 1: output j's pair at tap 0 (rows r + j, r + j), shifted in below.
      above[j][v] = centre;
      below[j][v] = centre;
    }
  for (int k = 1; k <= r; ++k) {
    const __m512 w = _mm512_set1_ps(kernel[r + k]);
    for (int v = 0; v < N; ++v) {
      // Tap k: output j reads rows r + j - k (output j - 1's at tap k - 1) and r + j + k (output
      // j + 1's at tap k - 1); two rows are new.
      for (int j = R - 1; j > 0; --j) above[j][v] = above[j - 1][v];
      above[0][v] = _mm512_maskz_loadu_ps(lanes(v), rows[r - k] + x + 16 * v);
      for (int j = 0; j + 1 < R; ++j) below[j][v] = below[j + 1][v];
      below[R - 1][v] = _mm512_maskz_loadu_ps(lanes(v), rows[r + R - 1 + k] + x + 16 * v);
      for (int j = 0; j < R; ++j) s[j][v] = _mm512_fmadd_ps(_mm512_add_ps(below[j][v], above[j][v]), w, s[j][v]);
    }
  }
  for (int j = 0; j < R; ++j)
    for (int v = 0; v < N; ++v) {
      _mm512_mask_storeu_ps(out[j] + x + 16 * v, lanes(v), s[j][v]);
      if (difference)
        _mm512_mask_storeu_ps(difference[j] + x + 16 * v, lanes(v),
                              _mm512_sub_ps(s[j][v], _mm512_maskz_loadu_ps(lanes(v), from[j] + x + 16 * v)));
    }
}

// R rows of the column pass over the row-filtered `rows`, as ColumnVectors describes.
template <int R>
__attribute__((target("avx512f"))) void BlurColumns(const float* const* rows, int cols, const float* kernel, int r,
                                                    float* const* out, const float* const* from,
                                                    float* const* difference) {
  int x = 0;
  for (; x + 32 <= cols; x += 32) ColumnVectors<R, 2>(rows, x, kernel, r, 0xFFFF, out, from, difference);
  for (; x < cols; x += 16) ColumnVectors<R, 1>(rows, x, kernel, r, LanesBefore(cols, x), out, from, difference);
}

// cv::GaussianBlur(src, dst, Size(), sigma, sigma) of a float image (its kernel, its borders,
// its order of operations), sixteen pixels at a time and on every core; with `difference`, also
// dst - src (cv::subtract's values) in the same pass.
void Blur(const cv::Mat& src, cv::Mat& dst, double sigma, cv::Mat* difference = nullptr) {
  const int ksize = cvRound(sigma * 4 * 2 + 1) | 1;
  const int r = ksize / 2;
  if (!FastSiftApplies() || src.type() != CV_32FC1 || ksize < 7 || src.cols < 2 || src.rows < 2) {
    cv::GaussianBlur(src, dst, cv::Size(), sigma, sigma);
    if (difference) cv::subtract(dst, src, *difference, cv::noArray(), CV_32F);
    return;
  }
  if (difference) difference->create(src.size(), CV_32F);
  cv::Mat kernel_mat = cv::getGaussianKernel(ksize, sigma, CV_32F);
  const float* kernel = kernel_mat.ptr<float>();
  std::vector<int> index(size_t(src.cols + 2 * r));
  for (int x = -r; x < src.cols + r; ++x) index[size_t(x + r)] = cv::borderInterpolate(x, src.cols, cv::BORDER_REFLECT_101);
  // Rows filtered across into a ring (in cache), then down four output rows at a time, band by band.
  constexpr int kRowsAtOnce = 4;
  const int ring_rows = ksize + kRowsAtOnce - 1;
  cv::Mat out(src.size(), CV_32F);
  const int bands = std::max(1, std::min(cv::getNumThreads(), src.rows / (4 * ksize)));
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    std::vector<float> ext(size_t(src.cols + 2 * r + 16));
    cv::Mat ring(ring_rows, src.cols, CV_32F);
    // The row each ring slot holds, by its index before reflection (y - r + i): indices in a
    // window of ring_rows never share a slot.
    std::vector<int> held(size_t(ring_rows), INT_MIN);
    std::vector<const float*> rows(static_cast<size_t>(ring_rows), nullptr);
    for (int band = range.start; band < range.end; ++band) {
      const int y0 = src.rows * band / bands, y1 = src.rows * (band + 1) / bands;
      for (int y = y0; y < y1;) {
        const int count = y1 - y >= kRowsAtOnce ? kRowsAtOnce : 1;
        for (int i = 0; i < ksize + count - 1; ++i) {
          const int unreflected = y - r + i;
          const int slot = ((unreflected % ring_rows) + ring_rows) % ring_rows;
          if (held[size_t(slot)] != unreflected) {
            const int row = cv::borderInterpolate(unreflected, src.rows, cv::BORDER_REFLECT_101);
            BlurRow(src.ptr<float>(row), src.cols, kernel, ksize, index.data(), ext.data(), ring.ptr<float>(slot));
            held[size_t(slot)] = unreflected;
          }
          rows[size_t(i)] = ring.ptr<float>(slot);
        }
        float* outs[kRowsAtOnce];
        const float* froms[kRowsAtOnce];
        float* differences[kRowsAtOnce];
        for (int j = 0; j < count; ++j) {
          outs[j] = out.ptr<float>(y + j);
          froms[j] = src.ptr<float>(y + j);
          differences[j] = difference ? difference->ptr<float>(y + j) : nullptr;
        }
        float* const* diff = difference ? differences : nullptr;
        if (count == kRowsAtOnce)
          BlurColumns<kRowsAtOnce>(rows.data(), src.cols, kernel, r, outs, froms, diff);
        else
          BlurColumns<1>(rows.data(), src.cols, kernel, r, outs, froms, diff);
        y += count;
      }
    }
  });
  dst = out;
}

}  // namespace

namespace {

// Output pixels 2k and 2k + 1 of a row doubled, for sixteen k: a[k - 1] / 4 + 3 a[k] / 4 and
// 3 a[k] / 4 + a[k + 1] / 4, each product rounded, then the sum (OpenCV's order, no fused
// multiply-add); `prev`, `mid` and `next` hold a[k - 1], a[k] and a[k + 1].
__attribute__((target("avx512f"))) inline void DoublePairs(__m512 prev, __m512 mid, __m512 next, float* out) {
  const __m512 quarter = _mm512_set1_ps(0.25f), three = _mm512_set1_ps(0.75f);
  const __m512 m = _mm512_mul_ps(mid, three);
  const __m512 even = _mm512_add_ps(_mm512_mul_ps(prev, quarter), m);
  const __m512 odd = _mm512_add_ps(m, _mm512_mul_ps(next, quarter));
  // Interleaved: even[0], odd[0], even[1], ...
  const __m512i lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
  const __m512i hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
  _mm512_storeu_ps(out, _mm512_permutex2var_ps(even, lo, odd));
  _mm512_storeu_ps(out + 16, _mm512_permutex2var_ps(even, hi, odd));
}

// a * wa + b * wb, each product rounded, then the sum: in separate statements, which the
// compiler does not fuse into a multiply-add (OpenCV's code has none).
inline float Weighed(float a, float wa, float b, float wb) {
  const float p = a * wa;
  const float q = b * wb;
  return p + q;
}

// A row doubled across (2 cols values from cols >= 2) as OpenCV's INTER_LINEAR weighs it; at the
// two ends its source is clamped with weights 1 and 0 (the edge value times 1).
__attribute__((target("avx512f"))) void DoubleRow(const float* a, int cols, float* out) {
  out[0] = a[0] * 1.f;
  out[1] = Weighed(a[0], 0.75f, a[1], 0.25f);
  int k = 1;
  for (; k + 16 < cols; k += 16)  // a[k + 16] is the last one read
    DoublePairs(_mm512_loadu_ps(a + k - 1), _mm512_loadu_ps(a + k), _mm512_loadu_ps(a + k + 1), out + 2 * k);
  for (; k < cols - 1; ++k) {
    out[2 * k] = Weighed(a[k - 1], 0.25f, a[k], 0.75f);
    out[2 * k + 1] = Weighed(a[k], 0.75f, a[k + 1], 0.25f);
  }
  out[2 * k] = Weighed(a[k - 1], 0.25f, a[k], 0.75f);  // k = cols - 1
  out[2 * k + 1] = a[k] * 1.f;
}

// out = a * wa + b * wb (Weighed's), sixteen at a time.
__attribute__((target("avx512f"))) void BlendRows(const float* a, float wa, const float* b, float wb, int n,
                                                  float* out) {
  const __m512 va = _mm512_set1_ps(wa), vb = _mm512_set1_ps(wb);
  int x = 0;
  for (; x + 16 <= n; x += 16)
    _mm512_storeu_ps(out + x, _mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(a + x), va),
                                            _mm512_mul_ps(_mm512_loadu_ps(b + x), vb)));
  for (; x < n; ++x) out[x] = Weighed(a[x], wa, b[x], wb);
}

}  // namespace

cv::Mat DoubleLinear(const cv::Mat& f) {
  if (!FastSiftApplies() || f.type() != CV_32FC1 || f.cols < 2 || f.rows < 2) {
    cv::Mat out;
    cv::resize(f, out, cv::Size(f.cols * 2, f.rows * 2), 0, 0, cv::INTER_LINEAR);
    return out;
  }
  const int w = 2 * f.cols;
  cv::Mat out(f.rows * 2, w, CV_32F);
  cv::parallel_for_(cv::Range(0, f.rows), [&](const cv::Range& r) {
    // Source rows doubled across, the last three in a ring (row k in slot k % 3).
    cv::Mat ring(3, w, CV_32F);
    int held[3] = {-1, -1, -1};
    auto across = [&](int k) -> const float* {
      k = std::clamp(k, 0, f.rows - 1);  // rows are clamped at the ends, the weights are not
      float* p = ring.ptr<float>(k % 3);
      if (held[k % 3] != k) {
        DoubleRow(f.ptr<float>(k), f.cols, p);
        held[k % 3] = k;
      }
      return p;
    };
    for (int k = r.start; k < r.end; ++k) {
      // Output rows 2k and 2k + 1 from source rows k - 1, k, k + 1.
      const float *up = across(k - 1), *mid = across(k), *down = across(k + 1);
      BlendRows(up, 0.25f, mid, 0.75f, w, out.ptr<float>(2 * k));
      BlendRows(mid, 0.75f, down, 0.25f, w, out.ptr<float>(2 * k + 1));
    }
  });
  return out;
}

namespace {

// A row's even-column values, out[x] = in[2 x] for x < n: sixteen from 32 by one permute.
__attribute__((target("avx512f"))) void EvenColumns(const float* in, int n, float* out) {
  const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  int x = 0;
  for (; x + 16 <= n; x += 16)
    _mm512_storeu_ps(out + x, _mm512_permutex2var_ps(_mm512_loadu_ps(in + 2 * x), even,
                                                     _mm512_loadu_ps(in + 2 * x + 16)));
  for (; x < n; ++x) out[x] = in[2 * x];
}

// The next octave's base: every other pixel of every other row, which is cv::resize's
// INTER_NEAREST to half the size (cols / 2 x rows / 2: source pixel 2x, 2y) without its
// dispatch and thread pool.
cv::Mat HalveNearest(const cv::Mat& src) {
  cv::Mat dst(src.rows / 2, src.cols / 2, CV_32F);
  for (int y = 0; y < dst.rows; ++y) EvenColumns(src.ptr<float>(2 * y), dst.cols, dst.ptr<float>(y));
  return dst;
}

}  // namespace

bool FastSiftApplies() { return CpuHasAvx512(); }

cv::Mat SiftBaseImage(const cv::Mat& gray, bool doubled, float sigma) {
  cv::Mat f, out;
  gray.convertTo(f, CV_32F, 1, 0);
  if (doubled) {
    const float diff = std::sqrt(std::max(sigma * sigma - kInitSigma * kInitSigma * 4, 0.01f));
    Blur(DoubleLinear(f), out, diff);
    return out;
  }
  const float diff = std::sqrt(std::max(sigma * sigma - kInitSigma * kInitSigma, 0.01f));
  Blur(f, out, diff);
  return out;
}

std::vector<std::vector<cv::Mat>> SiftGaussianPyramid(const cv::Mat& base, int octaves, int layers, int top,
                                                      double sigma, std::vector<std::vector<cv::Mat>>* dog) {
  std::vector<double> sig(static_cast<size_t>(layers + 3));
  sig[0] = sigma;
  const double k = std::pow(2., 1. / layers);
  for (int i = 1; i < layers + 3; i++) {
    const double prev = std::pow(k, double(i - 1)) * sigma, total = prev * k;
    sig[size_t(i)] = std::sqrt(total * total - prev * prev);
  }
  std::vector<std::vector<cv::Mat>> pyramid(static_cast<size_t>(octaves));
  if (dog) dog->assign(static_cast<size_t>(octaves), {});
  for (int o = 0; o < octaves; ++o) {
    auto& level = pyramid[size_t(o)];
    const int last = o + 1 < octaves ? std::max(top, layers) : top;
    level.resize(static_cast<size_t>(last + 1));
    if (o == 0) {
      level[0] = base;
    } else {
      const cv::Mat& src = pyramid[size_t(o - 1)][size_t(layers)];
      if (FastSiftApplies() && src.type() == CV_32F)
        level[0] = HalveNearest(src);
      else
        cv::resize(src, level[0], cv::Size(src.cols / 2, src.rows / 2), 0, 0, cv::INTER_NEAREST);
    }
    if (dog) (*dog)[size_t(o)].resize(static_cast<size_t>(last));
    for (int i = 1; i <= last; ++i)
      Blur(level[size_t(i - 1)], level[size_t(i)], sig[size_t(i)], dog ? &(*dog)[size_t(o)][size_t(i - 1)] : nullptr);
  }
  return pyramid;
}

void UnpackSiftOctave(const cv::KeyPoint& k, int* octave, int* layer, float* scale) {
  *octave = k.octave & 255;
  *layer = (k.octave >> 8) & 255;
  *octave = *octave < 128 ? *octave : (-128 | *octave);
  *scale = *octave >= 0 ? 1.f / static_cast<float>(1 << *octave) : static_cast<float>(1 << -*octave);
}

}  // namespace rolamos
