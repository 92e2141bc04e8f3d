#include "engine/sift_pyramid.h"
#include "util/cpu_features.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include <immintrin.h>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

namespace rolamos {

namespace {

constexpr float kInitSigma = 0.5f;  // the blur the input image is assumed to have (OpenCV's)

// Row y of `src` filtered by `kernel` (ksize taps, borders reflected): out[x] = sum_k
// kernel[k] src[x - r + k], accumulated from k = 0 by fused multiply-adds, as OpenCV's AVX2 row
// filter does it.
__attribute__((target("avx512f"))) void BlurRow(const float* row, int cols, const float* kernel, int ksize,
                                                const int* index, float* ext, float* out) {
  const int r = ksize / 2;
  std::memcpy(ext + r, row, sizeof(float) * size_t(cols));
  for (int x = 0; x < r; ++x) ext[x] = row[index[x]];
  for (int x = cols + r; x < cols + 2 * r; ++x) ext[x] = row[index[x]];
  // Four vectors' sums at once: each is a chain of ksize multiply-adds in OpenCV's order, which
  // one at a time would wait on the previous one's latency.
  int x = 0;
  for (; x + 64 <= cols; x += 64) {
    __m512 s0 = _mm512_setzero_ps(), s1 = s0, s2 = s0, s3 = s0;
    for (int k = 0; k < ksize; ++k) {
      const __m512 w = _mm512_set1_ps(kernel[k]);
      const float* e = ext + x + k;
      s0 = _mm512_fmadd_ps(_mm512_loadu_ps(e), w, s0);
      s1 = _mm512_fmadd_ps(_mm512_loadu_ps(e + 16), w, s1);
      s2 = _mm512_fmadd_ps(_mm512_loadu_ps(e + 32), w, s2);
      s3 = _mm512_fmadd_ps(_mm512_loadu_ps(e + 48), w, s3);
    }
    _mm512_storeu_ps(out + x, s0);
    _mm512_storeu_ps(out + x + 16, s1);
    _mm512_storeu_ps(out + x + 32, s2);
    _mm512_storeu_ps(out + x + 48, s3);
  }
  for (; x < cols; x += 16) {
    const __mmask16 m = cols - x >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (cols - x)) - 1);
    __m512 s = _mm512_setzero_ps();
    for (int k = 0; k < ksize; ++k) s = _mm512_fmadd_ps(_mm512_maskz_loadu_ps(m, ext + x + k), _mm512_set1_ps(kernel[k]), s);
    _mm512_mask_storeu_ps(out + x, m, s);
  }
}

// Row y of the column pass over the row-filtered `rows` (rows[k] is row y + k - r, reflected):
// the centre times the middle tap, then each pair of rows about it summed and multiplied in, as
// OpenCV's symmetric AVX2 column filter does it.
// With `from` and `difference`, also difference = out - from (the source's row y): SIFT's
// difference of Gaussians while the row is in registers, as cv::subtract computes it.
__attribute__((target("avx512f"))) void BlurColumn(const float* const* rows, int cols, const float* kernel, int r,
                                                   float* out, const float* from, float* difference) {
  // Four vectors at once, as in BlurRow.
  int x = 0;
  for (; x + 64 <= cols; x += 64) {
    const __m512 c = _mm512_set1_ps(kernel[r]);
    __m512 s[4];
    for (int v = 0; v < 4; ++v) s[v] = _mm512_mul_ps(_mm512_loadu_ps(rows[r] + x + 16 * v), c);
    for (int k = 1; k <= r; ++k) {
      const __m512 w = _mm512_set1_ps(kernel[r + k]);
      const float *below = rows[r + k] + x, *above = rows[r - k] + x;
      for (int v = 0; v < 4; ++v)
        s[v] = _mm512_fmadd_ps(_mm512_add_ps(_mm512_loadu_ps(below + 16 * v), _mm512_loadu_ps(above + 16 * v)), w, s[v]);
    }
    for (int v = 0; v < 4; ++v) _mm512_storeu_ps(out + x + 16 * v, s[v]);
    if (difference)
      for (int v = 0; v < 4; ++v)
        _mm512_storeu_ps(difference + x + 16 * v, _mm512_sub_ps(s[v], _mm512_loadu_ps(from + x + 16 * v)));
  }
  for (; x < cols; x += 16) {
    const __mmask16 m = cols - x >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (cols - x)) - 1);
    __m512 s = _mm512_mul_ps(_mm512_maskz_loadu_ps(m, rows[r] + x), _mm512_set1_ps(kernel[r]));
    for (int k = 1; k <= r; ++k) {
      const __m512 pair = _mm512_add_ps(_mm512_maskz_loadu_ps(m, rows[r + k] + x), _mm512_maskz_loadu_ps(m, rows[r - k] + x));
      s = _mm512_fmadd_ps(pair, _mm512_set1_ps(kernel[r + k]), s);
    }
    _mm512_mask_storeu_ps(out + x, m, s);
    if (difference) _mm512_mask_storeu_ps(difference + x, m, _mm512_sub_ps(s, _mm512_maskz_loadu_ps(m, from + x)));
  }
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
  // Rows filtered across into a ring of the last ksize (in cache), then down, band by band.
  cv::Mat out(src.size(), CV_32F);
  const int bands = std::max(1, std::min(cv::getNumThreads(), src.rows / (4 * ksize)));
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    std::vector<float> ext(size_t(src.cols + 2 * r + 16));
    cv::Mat ring(ksize, src.cols, CV_32F);
    std::vector<int> held(size_t(ksize), -1);  // the source row each ring row holds
    std::vector<const float*> rows(static_cast<size_t>(ksize), nullptr);
    for (int band = range.start; band < range.end; ++band) {
      const int y0 = src.rows * band / bands, y1 = src.rows * (band + 1) / bands;
      for (int y = y0; y < y1; ++y) {
        for (int k = 0; k < ksize; ++k) {
          const int from = cv::borderInterpolate(y + k - r, src.rows, cv::BORDER_REFLECT_101);
          const int slot = from % ksize;
          if (held[size_t(slot)] != from) {
            BlurRow(src.ptr<float>(from), src.cols, kernel, ksize, index.data(), ext.data(), ring.ptr<float>(slot));
            held[size_t(slot)] = from;
          }
          rows[size_t(k)] = ring.ptr<float>(slot);
        }
        BlurColumn(rows.data(), src.cols, kernel, r, out.ptr<float>(y), src.ptr<float>(y),
                   difference ? difference->ptr<float>(y) : nullptr);
      }
    }
  });
  dst = out;
}

}  // namespace

bool FastSiftApplies() { return CpuHasAvx512(); }

cv::Mat SiftBaseImage(const cv::Mat& gray, bool doubled, float sigma) {
  cv::Mat f, out;
  gray.convertTo(f, CV_32F, 1, 0);
  if (doubled) {
    const float diff = std::sqrt(std::max(sigma * sigma - kInitSigma * kInitSigma * 4, 0.01f));
    cv::Mat twice;
    cv::resize(f, twice, cv::Size(f.cols * 2, f.rows * 2), 0, 0, cv::INTER_LINEAR);
    Blur(twice, out, diff);
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
