#include "engine/corner_peaks.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <immintrin.h>

#include <opencv2/core.hpp>

#include "rolamos/error.hpp"
#include "util/cpu_features.h"

namespace rolamos {
namespace {

// Reflected rows and columns around the image: a peak's 5 x 5 of responses, each a 3 x 3 of
// gradients, each a 3 x 3 of pixels. The extra columns on the right take sixteen-pixel loads.
constexpr int kPad = 4;
constexpr int kTail = 16;
// OpenCV's gradient scale for an 8-bit image, a 3 x 3 aperture and block (1 / (4 x 3 x 255)),
// squared, and halved as its eigenvalue formula halves the diagonal.
constexpr float kSquare = float(1.0 / (3060.0 * 3060.0));
constexpr float kHalfSquare = float(0.5 / (3060.0 * 3060.0));

// Where responses are needed: the peaks' rows and columns and two more each way.
struct Region {
  int x0, x1, y0, y1;
  Region(cv::Size s, int border)
      : x0(std::max(border - 2, 0)), x1(std::min(s.width - border + 2, s.width)),
        y0(std::max(border - 2, 0)), y1(std::min(s.height - border + 2, s.height)) {}
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
};

// The sums are exact integers below 2^24 (9 x 1020^2), so each is exact as a float too.
inline float Response(int32_t xx, int32_t xy, int32_t yy) {
  const float a = float(xx) * kHalfSquare, c = float(yy) * kHalfSquare, b = float(xy) * kSquare;
  return (a + c) - std::sqrt((a - c) * (a - c) + b * b);
}

// Three product rows (xx, xy, yy) of the gradients at columns x0 - 1 .., and their sum down.
struct Rows {
  int width;  // columns held, a multiple of 16 with one vector to spare
  std::vector<int32_t> data;
  explicit Rows(int columns) : width((columns + 31) / 16 * 16), data(size_t(width) * 12, 0) {}
  int32_t* Products(int row, int channel) { return data.data() + size_t((((row % 3 + 3) % 3) * 3 + channel) * width); }
  int32_t* Down(int channel) { return data.data() + size_t((9 + channel) * width); }
};

void ProductsScalar(const cv::Mat& padded, int y, const Region& g, Rows& rows) {
  const uchar* up = padded.ptr(y + kPad - 1) + kPad + g.x0 - 1;
  const uchar* mid = padded.ptr(y + kPad) + kPad + g.x0 - 1;
  const uchar* down = padded.ptr(y + kPad + 1) + kPad + g.x0 - 1;
  int32_t *xx = rows.Products(y, 0), *xy = rows.Products(y, 1), *yy = rows.Products(y, 2);
  for (int i = 0; i < g.width() + 2; ++i) {
    const int gx = (up[i + 1] - up[i - 1]) + 2 * (mid[i + 1] - mid[i - 1]) + (down[i + 1] - down[i - 1]);
    const int gy = (down[i - 1] + 2 * down[i] + down[i + 1]) - (up[i - 1] + 2 * up[i] + up[i + 1]);
    xx[i] = gx * gx;
    xy[i] = gx * gy;
    yy[i] = gy * gy;
  }
}

void ResponsesScalar(const Region& g, Rows& rows, float* out) {
  for (int c = 0; c < 3; ++c) {
    const int32_t *a = rows.Products(0, c), *b = rows.Products(1, c), *d = rows.Products(2, c);
    int32_t* v = rows.Down(c);
    for (int i = 0; i < g.width() + 2; ++i) v[i] = a[i] + b[i] + d[i];
  }
  const int32_t *xx = rows.Down(0), *xy = rows.Down(1), *yy = rows.Down(2);
  for (int i = 0; i < g.width(); ++i)
    out[i] = Response(xx[i] + xx[i + 1] + xx[i + 2], xy[i] + xy[i + 1] + xy[i + 2], yy[i] + yy[i + 1] + yy[i + 2]);
}

__attribute__((target("avx512f"))) inline __m512i Bytes(const uchar* p) {
  return _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
}

__attribute__((target("avx512f"))) void ProductsAvx512(const cv::Mat& padded, int y, const Region& g, Rows& rows) {
  const uchar* up = padded.ptr(y + kPad - 1) + kPad + g.x0 - 1;
  const uchar* mid = padded.ptr(y + kPad) + kPad + g.x0 - 1;
  const uchar* down = padded.ptr(y + kPad + 1) + kPad + g.x0 - 1;
  int32_t *xx = rows.Products(y, 0), *xy = rows.Products(y, 1), *yy = rows.Products(y, 2);
  for (int i = 0; i < g.width() + 2; i += 16) {
    const __m512i ul = Bytes(up + i - 1), uc = Bytes(up + i), ur = Bytes(up + i + 1);
    const __m512i ml = Bytes(mid + i - 1), mr = Bytes(mid + i + 1);
    const __m512i dl = Bytes(down + i - 1), dc = Bytes(down + i), dr = Bytes(down + i + 1);
    const __m512i mx = _mm512_sub_epi32(mr, ml);
    const __m512i gx = _mm512_add_epi32(_mm512_add_epi32(_mm512_sub_epi32(ur, ul), _mm512_add_epi32(mx, mx)),
                                        _mm512_sub_epi32(dr, dl));
    const __m512i lower = _mm512_add_epi32(_mm512_add_epi32(dl, _mm512_add_epi32(dc, dc)), dr);
    const __m512i upper = _mm512_add_epi32(_mm512_add_epi32(ul, _mm512_add_epi32(uc, uc)), ur);
    const __m512i gy = _mm512_sub_epi32(lower, upper);
    _mm512_storeu_si512(xx + i, _mm512_mullo_epi32(gx, gx));
    _mm512_storeu_si512(xy + i, _mm512_mullo_epi32(gx, gy));
    _mm512_storeu_si512(yy + i, _mm512_mullo_epi32(gy, gy));
  }
}

__attribute__((target("avx512f"))) __m512i Across(const int32_t* v, int i) {
  return _mm512_add_epi32(_mm512_add_epi32(_mm512_loadu_si512(v + i), _mm512_loadu_si512(v + i + 1)),
                          _mm512_loadu_si512(v + i + 2));
}

__attribute__((target("avx512f"))) void ResponsesAvx512(const Region& g, Rows& rows, float* out) {
  for (int c = 0; c < 3; ++c) {
    const int32_t *a = rows.Products(0, c), *b = rows.Products(1, c), *d = rows.Products(2, c);
    int32_t* v = rows.Down(c);
    for (int i = 0; i < g.width() + 2; i += 16)
      _mm512_storeu_si512(v + i, _mm512_add_epi32(_mm512_add_epi32(_mm512_loadu_si512(a + i), _mm512_loadu_si512(b + i)),
                                                  _mm512_loadu_si512(d + i)));
  }
  const __m512 half_square = _mm512_set1_ps(kHalfSquare), square = _mm512_set1_ps(kSquare);
  for (int i = 0; i < g.width(); i += 16) {
    const __m512 a = _mm512_mul_ps(_mm512_cvtepi32_ps(Across(rows.Down(0), i)), half_square);
    const __m512 b = _mm512_mul_ps(_mm512_cvtepi32_ps(Across(rows.Down(1), i)), square);
    const __m512 c = _mm512_mul_ps(_mm512_cvtepi32_ps(Across(rows.Down(2), i)), half_square);
    const __m512 d = _mm512_sub_ps(a, c);
    const __m512 root = _mm512_sqrt_ps(_mm512_add_ps(_mm512_mul_ps(d, d), _mm512_mul_ps(b, b)));
    _mm512_storeu_ps(out + i, _mm512_sub_ps(_mm512_add_ps(a, c), root));
  }
}

// Responses over the region, a row per region row, with a vector's worth of spare columns.
cv::Mat Responses(const cv::Mat& gray, const Region& g, bool vector) {
  cv::Mat padded;
  cv::copyMakeBorder(gray, padded, kPad, kPad, kPad, kPad + kTail, cv::BORDER_REFLECT_101);
  Rows rows(g.width() + 2);
  cv::Mat out(g.height(), rows.width, CV_32F, cv::Scalar(0));
  auto products = vector ? ProductsAvx512 : ProductsScalar;
  for (int y = g.y0 - 1; y < g.y0 + 1; ++y) products(padded, y, g, rows);
  for (int y = g.y0; y < g.y1; ++y) {
    products(padded, y + 1, g, rows);
    (vector ? ResponsesAvx512 : ResponsesScalar)(g, rows, out.ptr<float>(y - g.y0));
  }
  return out;
}

void PeaksScalar(const cv::Mat& r, const Region& g, int border, cv::Size size, float least,
                 std::vector<CornerPeak>* peaks) {
  for (int y = border; y < size.height - border; ++y) {
    const float* row = r.ptr<float>(y - g.y0);
    for (int x = border; x < size.width - border; ++x) {
      const float e = row[x - g.x0];
      if (!(e > least)) continue;
      float most = e;
      for (int dy = -2; dy <= 2; ++dy) {
        const float* q = r.ptr<float>(y + dy - g.y0) + (x - g.x0);
        for (int dx = -2; dx <= 2; ++dx) most = std::max(most, q[dx]);
      }
      if (e >= most) peaks->push_back({e, x, y});
    }
  }
}

__attribute__((target("avx512f"))) void PeaksAvx512(const cv::Mat& r, const Region& g, int border, cv::Size size,
                                                    float least, std::vector<CornerPeak>* peaks) {
  const __m512 floor = _mm512_set1_ps(least);
  const int end = size.width - border;
  for (int y = border; y < size.height - border; ++y) {
    const float* row = r.ptr<float>(y - g.y0);
    for (int x = border; x < end; x += 16) {
      const __m512 e = _mm512_loadu_ps(row + (x - g.x0));
      __mmask16 wanted = _mm512_cmp_ps_mask(e, floor, _CMP_GT_OQ);
      if (end - x < 16) wanted &= static_cast<__mmask16>((1u << (end - x)) - 1);
      if (!wanted) continue;
      __m512 most = e;
      for (int dy = -2; dy <= 2; ++dy) {
        const float* q = r.ptr<float>(y + dy - g.y0) + (x - g.x0);
        for (int dx = -2; dx <= 2; ++dx) most = _mm512_max_ps(most, _mm512_loadu_ps(q + dx));
      }
      alignas(64) float value[16];
      _mm512_store_ps(value, e);
      for (unsigned m = wanted & _mm512_cmp_ps_mask(e, most, _CMP_GE_OQ); m; m &= m - 1) {
        const int l = __builtin_ctz(m);
        peaks->push_back({value[l], x + l, y});
      }
    }
  }
}

std::vector<CornerPeak> Find(const cv::Mat& gray, int border, float least, bool vector) {
  if (gray.type() != CV_8UC1)
    Fail("corner peaks", "image type " + cv::typeToString(gray.type()) + " is not 8-bit grey");
  // Within 3 pixels of the edge, OpenCV reflects the sums of products, not the image.
  if (border < 3) Fail("corner peaks", "a border of " + std::to_string(border) + " pixels is under 3");
  std::vector<CornerPeak> peaks;
  if (gray.cols <= 2 * border || gray.rows <= 2 * border) return peaks;
  const Region g(gray.size(), border);
  const cv::Mat r = Responses(gray, g, vector);
  (vector ? PeaksAvx512 : PeaksScalar)(r, g, border, gray.size(), least, &peaks);
  return peaks;
}

}  // namespace

std::vector<CornerPeak> CornerPeaks(const cv::Mat& gray, int border, float least) {
  return Find(gray, border, least, CpuHasAvx512());
}

namespace internal {
std::vector<CornerPeak> CornerPeaksScalar(const cv::Mat& gray, int border, float least) {
  return Find(gray, border, least, false);
}
}  // namespace internal

}  // namespace rolamos
