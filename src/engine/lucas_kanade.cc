#include "engine/lucas_kanade.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <functional>

#include <immintrin.h>
#include <opencv2/video/tracking.hpp>

#include "util/cpu_features.h"

namespace rolamos {
namespace {

constexpr int kWBits = 14;                   // bilinear weights' precision
constexpr float kFltScale = 1.f / (1 << 20);  // products of (intensity x 32) and derivatives, back to floats

int Descale(int v, int n) { return (v + (1 << (n - 1))) >> n; }

struct Weights {
  int w00, w01, w10, w11;
};

Weights WeightsAt(float a, float b) {
  Weights w;
  w.w00 = cvRound((1.f - a) * (1.f - b) * (1 << kWBits));
  w.w01 = cvRound(a * (1.f - b) * (1 << kWBits));
  w.w10 = cvRound((1.f - a) * b * (1 << kWBits));
  w.w11 = (1 << kWBits) - w.w00 - w.w01 - w.w10;
  return w;
}

// Two int16 weights in each 32-bit lane, for one multiply-add per pixel pair.
int Pair(int lo, int hi) { return int((uint32_t(lo) & 0xffffu) | (uint32_t(hi) << 16)); }

// A window of the first image at a point: intensities (x 32) and derivatives, `stride` values a
// row (a multiple of 8); derivatives are zero beyond the window's width, so whole vector rows can
// be summed. It points into a scratch buffer or into prepared templates.
struct Window {
  int w = 0, h = 0, stride = 0;
  int16_t* i = nullptr;
  int16_t* ix = nullptr;
  int16_t* iy = nullptr;
};

// Rows are taken 16 pixels at a time and, for the last 8 or fewer, 8 (a 21-pixel row: 16 + 8).
int StrideFor(cv::Size window) { return (window.width + 7) / 8 * 8; }
size_t ValuesFor(cv::Size window) { return size_t(3 * StrideFor(window) * window.height); }

Window WindowAt(int16_t* values, cv::Size window) {
  Window w;
  w.w = window.width, w.h = window.height, w.stride = StrideFor(window);
  const size_t plane = size_t(w.stride * w.h);
  w.i = values, w.ix = values + plane, w.iy = values + 2 * plane;
  return w;
}

// A window's second moments, ready for the iterations; not `ok` where the point is off the
// first image or its window too flat at that level (OpenCV gives up on such a point there).
struct Moments {
  float A11 = 0, A12 = 0, A22 = 0, D = 0;  // D: the inverse determinant
  bool ok = false;
};

// Where a pyramid level starts and how wide each row may be read.
struct FromLevel {
  const cv::Mat* I = nullptr;   // intensities
  const cv::Mat* dI = nullptr;  // derivatives (CV_16SC2)
  int readable_i = 0, readable_d = 0;  // columns readable from column 0, border included
};
struct ToLevel {
  const cv::Mat* J = nullptr;
  int readable_j = 0;
};

// The template of the window whose top-left pixel is `src` / `dsrc`; returns the sums of
// Ix Ix, Ix Iy, Iy Iy.
void TemplateScalar(const uchar* src, size_t si, const int16_t* dsrc, size_t sd, const Weights& w, Window& win,
                    float* A) {
  float a11 = 0, a12 = 0, a22 = 0;
  for (int y = 0; y < win.h; ++y, src += si, dsrc += sd) {
    int16_t* irow = win.i + y * win.stride;
    int16_t* xrow = win.ix + y * win.stride;
    int16_t* yrow = win.iy + y * win.stride;
    for (int x = 0; x < win.w; ++x) {
      const int16_t* d = dsrc + 2 * x;
      const int ival = Descale(src[x] * w.w00 + src[x + 1] * w.w01 + src[x + si] * w.w10 + src[x + si + 1] * w.w11,
                               kWBits - 5);
      const int ixv = Descale(d[0] * w.w00 + d[2] * w.w01 + d[sd] * w.w10 + d[sd + 2] * w.w11, kWBits);
      const int iyv = Descale(d[1] * w.w00 + d[3] * w.w01 + d[sd + 1] * w.w10 + d[sd + 3] * w.w11, kWBits);
      irow[x] = int16_t(ival);
      xrow[x] = int16_t(ixv);
      yrow[x] = int16_t(iyv);
      a11 += float(ixv * ixv);
      a12 += float(ixv * iyv);
      a22 += float(iyv * iyv);
    }
    for (int x = win.w; x < win.stride; ++x) irow[x] = xrow[x] = yrow[x] = 0;
  }
  A[0] = a11, A[1] = a12, A[2] = a22;
}

// Sum over the window of (J - I) Ix and (J - I) Iy, J read from `src`.
void MismatchScalar(const uchar* src, size_t sj, const Weights& w, const Window& win, float* b) {
  float b1 = 0, b2 = 0;
  for (int y = 0; y < win.h; ++y, src += sj) {
    const int16_t* irow = win.i + y * win.stride;
    const int16_t* xrow = win.ix + y * win.stride;
    const int16_t* yrow = win.iy + y * win.stride;
    for (int x = 0; x < win.w; ++x) {
      const int diff = Descale(src[x] * w.w00 + src[x + 1] * w.w01 + src[x + sj] * w.w10 + src[x + sj + 1] * w.w11,
                               kWBits - 5) - irow[x];
      b1 += float(diff * xrow[x]);
      b2 += float(diff * yrow[x]);
    }
  }
  b[0] = b1, b[1] = b2;
}

__attribute__((target("avx2"))) float HorizontalSum(__m256 v) {
  __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
  s = _mm_add_ps(s, _mm_movehl_ps(s, s));
  s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
  return _mm_cvtss_f32(s);
}

// 16 pixels of an 8-bit image interpolated, as int16 x 32: unpacking pairs each pixel with its
// right neighbour for one multiply-add with the weights; the pack restores the pixel order.
__attribute__((target("avx2"))) __m256i Bilinear16(const uchar* p, size_t step, __m256i top, __m256i bottom) {
  const __m256i round = _mm256_set1_epi32(1 << (kWBits - 5 - 1));
  const __m256i t0 = _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  const __m256i t1 = _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 1)));
  const __m256i b0 = _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + step)));
  const __m256i b1 = _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + step + 1)));
  __m256i lo = _mm256_add_epi32(_mm256_madd_epi16(_mm256_unpacklo_epi16(t0, t1), top),
                                _mm256_madd_epi16(_mm256_unpacklo_epi16(b0, b1), bottom));
  __m256i hi = _mm256_add_epi32(_mm256_madd_epi16(_mm256_unpackhi_epi16(t0, t1), top),
                                _mm256_madd_epi16(_mm256_unpackhi_epi16(b0, b1), bottom));
  lo = _mm256_srai_epi32(_mm256_add_epi32(lo, round), kWBits - 5);
  hi = _mm256_srai_epi32(_mm256_add_epi32(hi, round), kWBits - 5);
  return _mm256_packs_epi32(lo, hi);
}

// The same for 8 pixels (a row's last ones).
__attribute__((target("avx2"))) __m128i Bilinear8(const uchar* p, size_t step, __m256i top, __m256i bottom) {
  const __m128i round = _mm_set1_epi32(1 << (kWBits - 5 - 1));
  const __m128i wt = _mm256_castsi256_si128(top), wb = _mm256_castsi256_si128(bottom);
  const __m128i t0 = _mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)));
  const __m128i t1 = _mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + 1)));
  const __m128i b0 = _mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + step)));
  const __m128i b1 = _mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + step + 1)));
  __m128i lo = _mm_add_epi32(_mm_madd_epi16(_mm_unpacklo_epi16(t0, t1), wt), _mm_madd_epi16(_mm_unpacklo_epi16(b0, b1), wb));
  __m128i hi = _mm_add_epi32(_mm_madd_epi16(_mm_unpackhi_epi16(t0, t1), wt), _mm_madd_epi16(_mm_unpackhi_epi16(b0, b1), wb));
  lo = _mm_srai_epi32(_mm_add_epi32(lo, round), kWBits - 5);
  hi = _mm_srai_epi32(_mm_add_epi32(hi, round), kWBits - 5);
  return _mm_packs_epi32(lo, hi);
}

// Packs 8 + 8 int32 into 16 int16 in order (packing works within 128-bit halves).
__attribute__((target("avx2"))) __m256i Pack16(__m256i a, __m256i b) {
  return _mm256_permute4x64_epi64(_mm256_packs_epi32(a, b), 0xD8);
}

// 8 pixels of the derivatives (Ix, Iy interleaved) interpolated, as two int32 vectors.
__attribute__((target("avx2"))) void Derivatives8(const int16_t* d, size_t step, __m256i top, __m256i bottom,
                                                  __m256i* gx, __m256i* gy) {
  const __m256i round = _mm256_set1_epi32(1 << (kWBits - 1));
  const __m256i d00 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(d));
  const __m256i d01 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(d + 2));
  const __m256i d10 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(d + step));
  const __m256i d11 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(d + step + 2));
  // Each 32-bit word is (Ix, Iy) of one pixel: pair a pixel's Ix with its neighbour's, and Iy.
  const __m256i xt = _mm256_blend_epi16(d00, _mm256_slli_epi32(d01, 16), 0xAA);
  const __m256i xb = _mm256_blend_epi16(d10, _mm256_slli_epi32(d11, 16), 0xAA);
  const __m256i yt = _mm256_blend_epi16(_mm256_srli_epi32(d00, 16), d01, 0xAA);
  const __m256i yb = _mm256_blend_epi16(_mm256_srli_epi32(d10, 16), d11, 0xAA);
  *gx = _mm256_srai_epi32(
      _mm256_add_epi32(_mm256_add_epi32(_mm256_madd_epi16(xt, top), _mm256_madd_epi16(xb, bottom)), round), kWBits);
  *gy = _mm256_srai_epi32(
      _mm256_add_epi32(_mm256_add_epi32(_mm256_madd_epi16(yt, top), _mm256_madd_epi16(yb, bottom)), round), kWBits);
}

__attribute__((target("avx2"))) void TemplateAvx2(const uchar* src, size_t si, const int16_t* dsrc, size_t sd,
                                                  const Weights& w, Window& win, float* A) {
  const __m256i top = _mm256_set1_epi32(Pair(w.w00, w.w01));
  const __m256i bottom = _mm256_set1_epi32(Pair(w.w10, w.w11));
  const __m256i lanes = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  __m256 a11 = _mm256_setzero_ps(), a12 = _mm256_setzero_ps(), a22 = _mm256_setzero_ps();
  for (int y = 0; y < win.h; ++y, src += si, dsrc += sd) {
    int16_t* irow = win.i + y * win.stride;
    int16_t* xrow = win.ix + y * win.stride;
    int16_t* yrow = win.iy + y * win.stride;
    __m256i r11 = _mm256_setzero_si256(), r12 = _mm256_setzero_si256(), r22 = _mm256_setzero_si256();
    for (int x = 0; x < win.stride; x += 16) {
      const bool half = x + 16 > win.stride;  // the row's last 8
      __m256i gx, gy;
      if (!half) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(irow + x), Bilinear16(src + x, si, top, bottom));
        __m256i gx0, gy0, gx1, gy1;
        Derivatives8(dsrc + 2 * x, sd, top, bottom, &gx0, &gy0);
        Derivatives8(dsrc + 2 * x + 16, sd, top, bottom, &gx1, &gy1);
        gx = Pack16(gx0, gx1);
        gy = Pack16(gy0, gy1);
      } else {
        _mm_storeu_si128(reinterpret_cast<__m128i*>(irow + x), Bilinear8(src + x, si, top, bottom));
        __m256i gx0, gy0;
        Derivatives8(dsrc + 2 * x, sd, top, bottom, &gx0, &gy0);
        gx = Pack16(gx0, _mm256_setzero_si256());  // upper 8 lanes zero
        gy = Pack16(gy0, _mm256_setzero_si256());
      }
      if (x + 16 > win.w) {  // beyond the window: no weight
        const __m256i inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(int16_t(win.w - x)), lanes);
        gx = _mm256_and_si256(gx, inside);
        gy = _mm256_and_si256(gy, inside);
      }
      if (!half) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(xrow + x), gx);
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(yrow + x), gy);
      } else {
        _mm_storeu_si128(reinterpret_cast<__m128i*>(xrow + x), _mm256_castsi256_si128(gx));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(yrow + x), _mm256_castsi256_si128(gy));
      }
      r11 = _mm256_add_epi32(r11, _mm256_madd_epi16(gx, gx));
      r12 = _mm256_add_epi32(r12, _mm256_madd_epi16(gx, gy));
      r22 = _mm256_add_epi32(r22, _mm256_madd_epi16(gy, gy));
    }
    a11 = _mm256_add_ps(a11, _mm256_cvtepi32_ps(r11));
    a12 = _mm256_add_ps(a12, _mm256_cvtepi32_ps(r12));
    a22 = _mm256_add_ps(a22, _mm256_cvtepi32_ps(r22));
  }
  A[0] = HorizontalSum(a11), A[1] = HorizontalSum(a12), A[2] = HorizontalSum(a22);
}

__attribute__((target("avx2"))) void MismatchAvx2(const uchar* src, size_t sj, const Weights& w, const Window& win,
                                                  float* b) {
  const __m256i top = _mm256_set1_epi32(Pair(w.w00, w.w01));
  const __m256i bottom = _mm256_set1_epi32(Pair(w.w10, w.w11));
  const int whole = win.stride / 16 * 16;  // then 8 more where the stride is not a multiple of 16
  __m256 b1 = _mm256_setzero_ps(), b2 = _mm256_setzero_ps();
  for (int y = 0; y < win.h; ++y, src += sj) {
    const int16_t* irow = win.i + y * win.stride;
    const int16_t* xrow = win.ix + y * win.stride;
    const int16_t* yrow = win.iy + y * win.stride;
    __m256i r1 = _mm256_setzero_si256(), r2 = _mm256_setzero_si256();
    for (int x = 0; x < whole; x += 16) {
      const __m256i diff = _mm256_sub_epi16(Bilinear16(src + x, sj, top, bottom),
                                            _mm256_loadu_si256(reinterpret_cast<const __m256i*>(irow + x)));
      r1 = _mm256_add_epi32(r1, _mm256_madd_epi16(diff, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(xrow + x))));
      r2 = _mm256_add_epi32(r2, _mm256_madd_epi16(diff, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(yrow + x))));
    }
    if (whole < win.stride) {
      const __m128i diff = _mm_sub_epi16(Bilinear8(src + whole, sj, top, bottom),
                                         _mm_loadu_si128(reinterpret_cast<const __m128i*>(irow + whole)));
      const __m128i p1 = _mm_madd_epi16(diff, _mm_loadu_si128(reinterpret_cast<const __m128i*>(xrow + whole)));
      const __m128i p2 = _mm_madd_epi16(diff, _mm_loadu_si128(reinterpret_cast<const __m128i*>(yrow + whole)));
      r1 = _mm256_add_epi32(r1, _mm256_inserti128_si256(_mm256_setzero_si256(), p1, 0));
      r2 = _mm256_add_epi32(r2, _mm256_inserti128_si256(_mm256_setzero_si256(), p2, 0));
    }
    b1 = _mm256_add_ps(b1, _mm256_cvtepi32_ps(r1));
    b2 = _mm256_add_ps(b2, _mm256_cvtepi32_ps(r2));
  }
  b[0] = HorizontalSum(b1), b[1] = HorizontalSum(b2);
}

struct Settings {
  cv::Size window;
  int max_count = 30;
  double epsilon2 = 1e-4;  // squared smallest step
  float min_eigen = 1e-4f;
  bool vectorised = false;
};

Settings SettingsFor(cv::Size window, const cv::TermCriteria& until, double min_eigen, bool vectorised) {
  Settings s;
  s.window = window;
  s.max_count = (until.type & cv::TermCriteria::COUNT) ? std::clamp(until.maxCount, 0, 100) : 30;
  const double eps = (until.type & cv::TermCriteria::EPS) ? std::clamp(until.epsilon, 0.0, 10.0) : 0.01;
  s.epsilon2 = eps * eps;
  s.min_eigen = float(min_eigen);
  s.vectorised = vectorised;
  return s;
}

cv::Point2f HalfWindow(cv::Size w) { return {(w.width - 1) * 0.5f, (w.height - 1) * 0.5f}; }

// The window of `from` at one level around `point` (level pixels) into `win`, and its moments.
Moments MakeTemplate(const FromLevel& lv, const Settings& s, cv::Point2f point, Window& win) {
  const cv::Size ws = s.window;
  const cv::Point2f prev = point - HalfWindow(ws);
  const cv::Point ip(cvFloor(prev.x), cvFloor(prev.y));
  if (ip.x < -ws.width || ip.x >= lv.dI->cols || ip.y < -ws.height || ip.y >= lv.dI->rows) return {};
  const Weights w = WeightsAt(prev.x - float(ip.x), prev.y - float(ip.y));
  const uchar* isrc = lv.I->data + ptrdiff_t(ip.y) * ptrdiff_t(lv.I->step) + ip.x;
  const size_t dstep = lv.dI->step / sizeof(int16_t);
  const int16_t* dsrc = reinterpret_cast<const int16_t*>(lv.dI->data) + ptrdiff_t(ip.y) * ptrdiff_t(dstep) + 2 * ip.x;
  float A[3];
  const bool wide = s.vectorised && ip.x + win.stride + 1 <= lv.readable_i && ip.x + win.stride + 1 <= lv.readable_d;
  (wide ? TemplateAvx2 : TemplateScalar)(isrc, lv.I->step, dsrc, dstep, w, win, A);
  Moments m;
  m.A11 = A[0] * kFltScale, m.A12 = A[1] * kFltScale, m.A22 = A[2] * kFltScale;
  const float D = m.A11 * m.A22 - m.A12 * m.A12;
  const float min_eigen = (m.A22 + m.A11 - std::sqrt((m.A11 - m.A22) * (m.A11 - m.A22) + 4.f * m.A12 * m.A12)) /
                          float(2 * ws.width * ws.height);
  if (min_eigen < s.min_eigen || D < FLT_EPSILON) return {};
  m.D = 1.f / D;
  m.ok = true;
  return m;
}

// Lucas-Kanade's steps at one level from `next` (level pixels); `out` follows each step.
// Returns false where the window left the second image.
bool Iterate(const ToLevel& lv, const Settings& s, const Moments& m, const Window& win, cv::Point2f next,
             cv::Point2f* out) {
  const cv::Size ws = s.window;
  const cv::Point2f half = HalfWindow(ws);
  next -= half;
  cv::Point2f last_delta;
  for (int j = 0; j < s.max_count; ++j) {
    const cv::Point in(cvFloor(next.x), cvFloor(next.y));
    if (in.x < -ws.width || in.x >= lv.J->cols || in.y < -ws.height || in.y >= lv.J->rows) return false;
    const Weights wj = WeightsAt(next.x - float(in.x), next.y - float(in.y));
    const uchar* jsrc = lv.J->data + ptrdiff_t(in.y) * ptrdiff_t(lv.J->step) + in.x;
    float b[2];
    const bool wide = s.vectorised && in.x + win.stride + 1 <= lv.readable_j;
    (wide ? MismatchAvx2 : MismatchScalar)(jsrc, lv.J->step, wj, win, b);
    const float b1 = b[0] * kFltScale, b2 = b[1] * kFltScale;
    const cv::Point2f delta(float((m.A12 * b2 - m.A22 * b1) * m.D), float((m.A12 * b1 - m.A11 * b2) * m.D));
    next += delta;
    *out = next + half;
    if (delta.ddot(delta) <= s.epsilon2) break;
    if (j > 0 && std::abs(delta.x + last_delta.x) < 0.01 && std::abs(delta.y + last_delta.y) < 0.01) {
      *out -= delta * 0.5f;  // oscillating: halfway
      break;
    }
    last_delta = delta;
  }
  return true;
}

// Where a point's window and moments at a level come from: made here, or prepared.
using TemplateSource = std::function<Moments(int level, Window* win)>;

// One point through every level, coarse to fine; OpenCV's LKTrackerInvoker's rules.
void FollowPoint(const std::vector<ToLevel>& levels, const Settings& s, const TemplateSource& windows,
                 cv::Point2f* to, uchar* status) {
  const int top = int(levels.size()) - 1;
  cv::Point2f out = *to;
  for (int level = top; level >= 0; --level) {
    out = level == top ? out * float(1. / (1 << level)) : out * 2.f;
    Window win;
    const Moments m = windows(level, &win);
    const bool followed = m.ok && Iterate(levels[size_t(level)], s, m, win, out, &out);
    if (!followed && level == 0) *status = 0;
  }
  *to = out;
}

// Whether `m` has at least `border` pixels around it in its parent buffer; `readable` gets how
// many columns from its column 0 can be read.
bool Bordered(const cv::Mat& m, int border, int* readable) {
  cv::Size whole;
  cv::Point ofs;
  m.locateROI(whole, ofs);
  *readable = whole.width - ofs.x;
  return ofs.x >= border && ofs.y >= border && ofs.x + m.cols + border <= whole.width &&
         ofs.y + m.rows + border <= whole.height;
}

int Border(cv::Size window) { return std::max(window.width, window.height); }

// The levels of a first image's pyramid (with derivatives) up to `levels`, with the borders the
// kernel reads; empty if it has not.
std::vector<FromLevel> FromLevels(const std::vector<cv::Mat>& pyramid, cv::Size window, int levels) {
  std::vector<FromLevel> out;
  for (int l = 0; l <= std::min(levels, int(pyramid.size()) / 2 - 1); ++l) {
    FromLevel lv;
    lv.I = &pyramid[size_t(2 * l)];
    lv.dI = &pyramid[size_t(2 * l + 1)];
    if (lv.I->type() != CV_8UC1 || lv.dI->type() != CV_16SC2 || lv.dI->size() != lv.I->size() ||
        !Bordered(*lv.I, Border(window), &lv.readable_i) || !Bordered(*lv.dI, Border(window), &lv.readable_d))
      return {};
    out.push_back(lv);
  }
  return out;
}

std::vector<ToLevel> ToLevels(const std::vector<cv::Mat>& pyramid, cv::Size window, int levels) {
  std::vector<ToLevel> out;
  const int step = pyramid.size() > 1 && pyramid[1].type() == CV_16SC2 ? 2 : 1;
  for (int l = 0; l <= std::min(levels, int(pyramid.size()) / step - 1); ++l) {
    ToLevel lv;
    lv.J = &pyramid[size_t(step * l)];
    if (lv.J->type() != CV_8UC1 || !Bordered(*lv.J, Border(window), &lv.readable_j)) return {};
    out.push_back(lv);
  }
  return out;
}

void OpenCvFollow(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                  const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found, std::vector<uchar>* status,
                  cv::Size window, int levels, const cv::TermCriteria& until, double min_eigen) {
  cv::calcOpticalFlowPyrLK(from, to, points, *found, *status, cv::noArray(), window, levels, until,
                           cv::OPTFLOW_USE_INITIAL_FLOW, min_eigen);
}

// `follow` (points, found, status) run on the points `only` picks out, its results put back in
// their places; the others' `found` and `status` left as they are.
template <typename Follow>
void FollowSome(const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found, std::vector<uchar>* status,
                const std::vector<int>& only, const Follow& follow) {
  status->resize(points.size(), 0);
  std::vector<cv::Point2f> some, there;
  std::vector<uchar> ok;
  for (int i : only) {
    some.push_back(points[size_t(i)]);
    there.push_back((*found)[size_t(i)]);
  }
  follow(some, &there, &ok);
  for (size_t k = 0; k < only.size(); ++k) {
    (*found)[size_t(only[k])] = there[k];
    (*status)[size_t(only[k])] = ok[k];
  }
}

void Follow(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to, const std::vector<cv::Point2f>& points,
            std::vector<cv::Point2f>* found, std::vector<uchar>* status, cv::Size window, int levels,
            const cv::TermCriteria& until, double min_eigen, bool vectorised) {
  const std::vector<FromLevel> a = FromLevels(from, window, levels);
  std::vector<ToLevel> b = ToLevels(to, window, levels);
  if (a.empty() || b.empty() || window.width > 64 || found->size() != points.size()) {
    OpenCvFollow(from, to, points, found, status, window, levels, until, min_eigen);  // not a pyramid we read
    return;
  }
  b.resize(std::min(a.size(), b.size()));
  const Settings s = SettingsFor(window, until, min_eigen, vectorised);
  status->assign(points.size(), 1);
  cv::parallel_for_(cv::Range(0, int(points.size())), [&](const cv::Range& r) {
    std::vector<int16_t> scratch(ValuesFor(window));
    for (int i = r.start; i < r.end; ++i) {
      const cv::Point2f p = points[size_t(i)];
      const TemplateSource make = [&](int level, Window* win) {
        *win = WindowAt(scratch.data(), window);
        return MakeTemplate(a[size_t(level)], s, p * float(1. / (1 << level)), *win);
      };
      FollowPoint(b, s, make, &(*found)[size_t(i)], &(*status)[size_t(i)]);
    }
  });
}

}  // namespace

class LucasKanadeTemplates {
 public:
  cv::Size window;
  int requested_levels = 0;
  int levels = -1;  // -1: not prepared (no AVX2, or a pyramid without borders): OpenCV follows
  double min_eigen = 0;
  size_t points = 0;
  // Point by point, level by level: a window's three planes. Not zeroed (3.6 MB for 300 points
  // at four levels): MakeTemplate writes every value of a window it makes, and a window it does
  // not make is never read (its moments are not ok).
  std::unique_ptr<int16_t[]> values;
  std::vector<Moments> moments;  // point * (levels + 1) + level

  size_t Slot(size_t point, int level) const { return point * size_t(levels + 1) + size_t(level); }
  Window At(size_t point, int level) const {
    return WindowAt(values.get() + Slot(point, level) * ValuesFor(window), window);
  }
};

std::shared_ptr<const LucasKanadeTemplates> PrepareLucasKanade(const std::vector<cv::Mat>& from,
                                                               const std::vector<cv::Point2f>& points,
                                                               cv::Size window, int levels, double min_eigen) {
  auto t = std::make_shared<LucasKanadeTemplates>();
  t->window = window;
  t->requested_levels = levels;
  t->min_eigen = min_eigen;
  t->points = points.size();
  const std::vector<FromLevel> a = FromLevels(from, window, levels);
  if (!CpuHasAvx2() || a.empty() || window.width > 64) return t;
  t->levels = int(a.size()) - 1;
  t->values.reset(new int16_t[points.size() * a.size() * ValuesFor(window)]);
  t->moments.resize(points.size() * a.size());
  const Settings s = SettingsFor(window, cv::TermCriteria(), min_eigen, true);
  cv::parallel_for_(cv::Range(0, int(points.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i)
      for (int l = 0; l <= t->levels; ++l) {
        Window win = t->At(size_t(i), l);
        t->moments[t->Slot(size_t(i), l)] = MakeTemplate(a[size_t(l)], s, points[size_t(i)] * float(1. / (1 << l)), win);
      }
  });
  return t;
}

void FollowLucasKanade(const LucasKanadeTemplates& windows, const std::vector<cv::Mat>& from,
                       const std::vector<cv::Mat>& to, const std::vector<cv::Point2f>& points,
                       std::vector<cv::Point2f>* found, std::vector<uchar>* status, const cv::TermCriteria& until,
                       const std::vector<int>* only) {
  CV_Assert(windows.points == points.size() && found->size() == points.size());
  std::vector<ToLevel> b = windows.levels < 0 ? std::vector<ToLevel>() : ToLevels(to, windows.window, windows.levels);
  if (b.empty()) {
    const auto opencv = [&](const std::vector<cv::Point2f>& some, std::vector<cv::Point2f>* there,
                            std::vector<uchar>* ok) {
      OpenCvFollow(from, to, some, there, ok, windows.window, windows.requested_levels, until, windows.min_eigen);
    };
    if (only) FollowSome(points, found, status, *only, opencv);
    else opencv(points, found, status);
    return;
  }
  status->resize(points.size(), 0);
  const Settings s = SettingsFor(windows.window, until, windows.min_eigen, true);
  const int n = only ? int(only->size()) : int(points.size());
  cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) {
      const int i = only ? (*only)[size_t(k)] : k;
      (*status)[size_t(i)] = 1;
      const TemplateSource prepared = [&](int level, Window* win) {
        *win = windows.At(size_t(i), level);
        return windows.moments[windows.Slot(size_t(i), level)];
      };
      FollowPoint(b, s, prepared, &(*found)[size_t(i)], &(*status)[size_t(i)]);
    }
  });
}

bool LucasKanadeVectorised() { return CpuHasAvx2(); }

void FollowLucasKanade(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                       const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                       std::vector<uchar>* status, cv::Size window, int levels, const cv::TermCriteria& until,
                       double min_eigen, const std::vector<int>* only) {
  const auto follow = [&](const std::vector<cv::Point2f>& some, std::vector<cv::Point2f>* there,
                          std::vector<uchar>* ok) {
    if (CpuHasAvx2()) Follow(from, to, some, there, ok, window, levels, until, min_eigen, true);
    else OpenCvFollow(from, to, some, there, ok, window, levels, until, min_eigen);
  };
  if (only) FollowSome(points, found, status, *only, follow);
  else follow(points, found, status);
}

namespace detail {
void FollowLucasKanadeScalar(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                             const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                             std::vector<uchar>* status, cv::Size window, int levels,
                             const cv::TermCriteria& until, double min_eigen) {
  Follow(from, to, points, found, status, window, levels, until, min_eigen, false);
}
}  // namespace detail

}  // namespace rolamos
