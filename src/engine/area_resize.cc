#include "engine/area_resize.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <vector>

#include <immintrin.h>

#include <opencv2/imgproc.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

// One source pixel's share of one destination pixel, along one axis.
struct Share {
  int source, dest;
  float weight;
};

// The shares along an axis of `ssize` pixels shrunk to `dsize` (`scale` source pixels to one), as
// OpenCV's INTER_AREA weighs them: each destination cell's whole source pixels at 1 / width,
// a partly covered pixel at either end by the part it covers, in the order of the source.
std::vector<Share> Shares(int ssize, int dsize, double scale) {
  std::vector<Share> out;
  for (int d = 0; d < dsize; ++d) {
    const double begin = d * scale, end = begin + scale;
    const double width = std::min(scale, ssize - begin);
    const int last = std::min(cvFloor(end), ssize - 1);
    const int first = std::min(cvCeil(begin), last);
    if (first - begin > 1e-3) out.push_back({first - 1, d, float((first - begin) / width)});
    for (int s = first; s < last; ++s) out.push_back({s, d, float(1.0 / width)});
    if (end - last > 1e-3) out.push_back({last, d, float(std::min(std::min(end - last, 1.), width) / width)});
  }
  return out;
}

// The horizontal shares laid out for sixteen destination pixels at a time: term m of pixel x at
// [m * stride + x]. Pixels with fewer terms than the most get terms of weight 0 after theirs
// (adding 0 to a sum of non-negative products leaves it as it was).
struct Columns {
  int stride = 0, terms = 0;
  std::vector<int> source;
  std::vector<float> weight;
};

// Interleaved channels: each share stands for `channels` values, a channel's to its own.
Columns LayOut(const std::vector<Share>& shares, int dsize, int channels) {
  Columns c;
  const int values = dsize * channels;
  c.stride = (values + 15) / 16 * 16;
  std::vector<int> count(size_t(dsize), 0);
  for (const Share& s : shares) c.terms = std::max(c.terms, ++count[size_t(s.dest)]);
  c.source.assign(size_t(c.terms) * size_t(c.stride), 0);
  c.weight.assign(size_t(c.terms) * size_t(c.stride), 0.f);
  std::fill(count.begin(), count.end(), 0);
  for (const Share& s : shares) {
    const size_t term = size_t(count[size_t(s.dest)]++);
    for (int ch = 0; ch < channels; ++ch) {
      const size_t at = term * size_t(c.stride) + size_t(s.dest * channels + ch);
      c.source[at] = s.source * channels + ch;
      c.weight[at] = s.weight;
    }
  }
  return c;
}

// Source row `row` (as floats) reduced across: out[x] = sum over its terms, in order, of the
// source pixel times its weight (a product, then a sum: no fused multiply-add, as OpenCV).
__attribute__((target("avx512f"))) void Across(const float* row, const Columns& c, float* out) {
  for (int x = 0; x < c.stride; x += 16) {
    __m512 sum = _mm512_setzero_ps();
    for (int m = 0; m < c.terms; ++m) {
      const size_t at = size_t(m) * size_t(c.stride) + size_t(x);
      const __m512i index = _mm512_loadu_si512(c.source.data() + at);
      const __m512 pixel = _mm512_i32gather_ps(index, row, 4);
      sum = _mm512_add_ps(sum, _mm512_mul_ps(pixel, _mm512_loadu_ps(c.weight.data() + at)));
    }
    _mm512_storeu_ps(out + x, sum);
  }
}

__attribute__((target("avx512f"))) void RowToFloat(const uchar* row, int n, float* out) {
  int x = 0;
  for (; x + 16 <= n; x += 16)
    _mm512_storeu_ps(out + x, _mm512_cvtepi32_ps(_mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(row + x)))));
  for (; x < n; ++x) out[x] = float(row[x]);
}

// sum = beta * across (first) or sum += beta * across, sixteen at a time.
__attribute__((target("avx512f"))) void Down(const float* across, float beta, bool first, int n, float* sum) {
  const __m512 b = _mm512_set1_ps(beta);
  for (int x = 0; x < n; x += 16) {
    const __m512 product = _mm512_mul_ps(b, _mm512_loadu_ps(across + x));
    _mm512_storeu_ps(sum + x, first ? product : _mm512_add_ps(_mm512_loadu_ps(sum + x), product));
  }
}

// The row of sums rounded (half to even, as cvRound) into 0..255.
__attribute__((target("avx512f"))) void Store(const float* sum, int n, uchar* out) {
  for (int x = 0; x < n; x += 16) {
    const __mmask16 m = n - x >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (n - x)) - 1);
    const __m512i v = _mm512_max_epi32(_mm512_cvtps_epi32(_mm512_loadu_ps(sum + x)), _mm512_setzero_si512());
    _mm512_mask_cvtusepi32_storeu_epi8(out + x, m, v);
  }
}

// column[k] += row[k] for `values` values (sums of at most 257 rows fit 16 bits).
__attribute__((target("avx512f,avx512bw"))) void AddRowWide(const uchar* row, int values, uint16_t* column) {
  int k = 0;
  for (; k + 32 <= values; k += 32) {
    const __m512i v = _mm512_cvtepu8_epi16(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(row + k)));
    _mm512_storeu_si512(column + k, _mm512_add_epi16(_mm512_loadu_si512(column + k), v));
  }
  for (; k < values; ++k) column[k] = uint16_t(column[k] + row[k]);
}

void AddRow(const uchar* row, int values, uint16_t* column) {
  if (CpuHasAvx512Bw()) return AddRowWide(row, values, column);
  for (int k = 0; k < values; ++k) column[k] = uint16_t(column[k] + row[k]);
}

// out[i] = saturate_cast<uchar>(float(sums[i]) * scale) for n values: cvRound's rounding.
__attribute__((target("avx512f,avx512bw"))) void FinishWide(const int* sums, int n, float scale, uchar* out) {
  const __m512 s = _mm512_set1_ps(scale);
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512i v = _mm512_cvtps_epi32(_mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_loadu_si512(sums + i)), s));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i), _mm512_cvtusepi32_epi8(_mm512_max_epi32(v, _mm512_setzero_si512())));
  }
  for (; i < n; ++i) out[i] = cv::saturate_cast<uchar>(float(sums[i]) * scale);
}

void Finish(const int* sums, int n, float scale, uchar* out) {
  if (CpuHasAvx512Bw()) return FinishWide(sums, n, scale, out);
  for (int i = 0; i < n; ++i) out[i] = cv::saturate_cast<uchar>(float(sums[i]) * scale);
}

// OpenCV's INTER_AREA for whole factors of 3 and more each way (its block-average path, which
// takes each value one at a time through a table of offsets): a block of sx x sy pixels is the
// sum of its values times 1 / (sx sy) in float, rounded; a block cut by the image's right or
// bottom edge is the sum over the pixels it holds divided by their count, in float. Sums are
// whole numbers, so the order they are added in does not matter: the pixels are OpenCV's.
void BlockAverage(const cv::Mat& src, cv::Mat& dst, cv::Size dsize, int sx, int sy) {
  const int cn = src.channels(), values = src.cols * cn;
  const float scale = 1.f / float(sx * sy);
  const int whole_cols = std::min(src.cols / sx, dsize.width);  // destination pixels over whole blocks of columns
  cv::Mat out(dsize, src.type());
  std::vector<uint16_t> column(static_cast<size_t>(values));
  std::vector<int> sums(static_cast<size_t>(dsize.width * cn));
  for (int dy = 0; dy < dsize.height; ++dy) {
    uchar* d = out.ptr<uchar>(dy);
    const int y0 = dy * sy, y1 = std::min(y0 + sy, src.rows);
    if (y0 >= src.rows) {
      std::fill(d, d + size_t(dsize.width) * size_t(cn), uchar(0));
      continue;
    }
    // Each source column's sum over the block's rows.
    std::fill(column.begin(), column.end(), uint16_t(0));
    for (int y = y0; y < y1; ++y) AddRow(src.ptr<uchar>(y), values, column.data());
    const bool whole_rows = y1 - y0 == sy;
    int dx = 0;
    if (whole_rows) {  // whole blocks: their sums, then scaled and rounded sixteen at a time
      for (; dx < whole_cols; ++dx)
        for (int c = 0; c < cn; ++c) {
          const uint16_t* p = column.data() + size_t(dx * sx * cn + c);
          int sum = 0;
          for (int x = 0; x < sx; ++x) sum += p[x * cn];
          sums[size_t(dx * cn + c)] = sum;
        }
      Finish(sums.data(), whole_cols * cn, scale, d);
    }
    for (; dx < dsize.width; ++dx) {  // blocks cut by the right or bottom edge (or past it)
      const int x0 = dx * sx, x1 = std::min(x0 + sx, src.cols);
      for (int c = 0; c < cn; ++c) {
        uchar& v = d[size_t(dx) * size_t(cn) + size_t(c)];
        if (x0 >= src.cols) {
          v = 0;
          continue;
        }
        int sum = 0;
        for (int x = x0; x < x1; ++x) sum += column[size_t(x * cn + c)];
        v = cv::saturate_cast<uchar>(float(sum) / float((x1 - x0) * (y1 - y0)));
      }
    }
  }
  dst = out;
}

// Whether OpenCV takes that path for an 8-bit `src` whose factors (source pixels to one, from
// the scale asked for or the sizes' ratio, as cv::resize has it) are fx, fy: whole numbers each
// way. Not for 2 or less each way, which OpenCV copies or rounds another way in its vectors.
bool BlockAverages(const cv::Mat& src, double fx, double fy, int* sx, int* sy) {
  *sx = cv::saturate_cast<int>(fx), *sy = cv::saturate_cast<int>(fy);
  return src.depth() == CV_8U && src.channels() <= 4 && fy <= 257 && fx >= 1 && fy >= 1 &&
         std::abs(fx - *sx) < DBL_EPSILON &&
         std::abs(fy - *sy) < DBL_EPSILON && !(*sx <= 2 && *sy <= 2);
}

}  // namespace

void ResizeArea(const cv::Mat& src, cv::Mat& dst, double scale) {
  const cv::Size dsize(cv::saturate_cast<int>(src.cols * scale), cv::saturate_cast<int>(src.rows * scale));
  // As cv::resize: the tables' scale is the inverse of the one asked for, not the sizes' ratio.
  const double inverse = 1. / scale;
  const bool whole = std::abs(inverse - cv::saturate_cast<int>(inverse)) < DBL_EPSILON;
  int sx, sy;
  if (dsize.area() > 0 && BlockAverages(src, inverse, inverse, &sx, &sy)) {
    BlockAverage(src, dst, dsize, sx, sy);
    return;
  }
  const int channels = src.channels();
  if (src.depth() != CV_8U || channels > 4 || !(scale > 0 && scale < 1) || whole || dsize.area() == 0 ||
      dsize == src.size() || !CpuHasAvx512()) {
    cv::resize(src, dst, cv::Size(), scale, scale, cv::INTER_AREA);
    return;
  }
  const Columns columns = LayOut(Shares(src.cols, dsize.width, inverse), dsize.width, channels);
  const std::vector<Share> rows = Shares(src.rows, dsize.height, inverse);
  cv::Mat out(dsize, src.type());
  const int values = src.cols * channels;
  std::vector<float> row(static_cast<size_t>(values)), across(static_cast<size_t>(columns.stride)),
      sum(static_cast<size_t>(columns.stride));
  int held = -1;  // the source row `across` holds (a row under two destination rows is reduced once)
  for (size_t j = 0; j < rows.size(); ++j) {
    const Share& s = rows[j];
    if (s.source != held) {
      RowToFloat(src.ptr<uchar>(s.source), values, row.data());
      Across(row.data(), columns, across.data());
      held = s.source;
    }
    const bool first = j == 0 || rows[j - 1].dest != s.dest;
    Down(across.data(), s.weight, first, columns.stride, sum.data());
    if (j + 1 == rows.size() || rows[j + 1].dest != s.dest)
      Store(sum.data(), dsize.width * channels, out.ptr<uchar>(s.dest));
  }
  dst = out;
}

void ResizeArea(const cv::Mat& src, cv::Mat& dst, cv::Size dsize) {
  int sx, sy;
  if (dsize.area() > 0 && !src.empty() &&
      BlockAverages(src, 1. / (double(dsize.width) / src.cols), 1. / (double(dsize.height) / src.rows), &sx, &sy)) {
    BlockAverage(src, dst, dsize, sx, sy);
    return;
  }
  cv::resize(src, dst, dsize, 0, 0, cv::INTER_AREA);
}

}  // namespace rolamos
