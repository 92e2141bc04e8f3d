#include "engine/lucas_kanade.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>

#include <immintrin.h>
#include <opencv2/video/tracking.hpp>

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
// row; derivatives are zero beyond the window's width, so whole vector rows can be summed.
struct Window {
  int w = 0, h = 0, stride = 0;
  std::vector<int16_t> i, ix, iy;
  explicit Window(cv::Size size)
      : w(size.width), h(size.height), stride((size.width + 15) / 16 * 16),
        i(size_t(stride * h)), ix(size_t(stride * h)), iy(size_t(stride * h)) {}
};

// Where one level's images start and how wide each row may be read.
struct Level {
  const cv::Mat* I = nullptr;   // first image
  const cv::Mat* dI = nullptr;  // its derivatives (CV_16SC2)
  const cv::Mat* J = nullptr;   // second image
  int readable_i = 0, readable_d = 0, readable_j = 0;  // columns readable from column 0 (border included)
};

// The template of the window whose top-left pixel is `src` / `dsrc`; returns the sums of
// Ix Ix, Ix Iy, Iy Iy.
void TemplateScalar(const uchar* src, size_t si, const int16_t* dsrc, size_t sd, const Weights& w, Window& win,
                    float* A) {
  float a11 = 0, a12 = 0, a22 = 0;
  for (int y = 0; y < win.h; ++y, src += si, dsrc += sd) {
    int16_t* irow = win.i.data() + y * win.stride;
    int16_t* xrow = win.ix.data() + y * win.stride;
    int16_t* yrow = win.iy.data() + y * win.stride;
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
    const int16_t* irow = win.i.data() + y * win.stride;
    const int16_t* xrow = win.ix.data() + y * win.stride;
    const int16_t* yrow = win.iy.data() + y * win.stride;
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
    int16_t* irow = win.i.data() + y * win.stride;
    int16_t* xrow = win.ix.data() + y * win.stride;
    int16_t* yrow = win.iy.data() + y * win.stride;
    __m256i r11 = _mm256_setzero_si256(), r12 = _mm256_setzero_si256(), r22 = _mm256_setzero_si256();
    for (int x = 0; x < win.stride; x += 16) {
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(irow + x), Bilinear16(src + x, si, top, bottom));
      __m256i gx0, gy0, gx1, gy1;
      Derivatives8(dsrc + 2 * x, sd, top, bottom, &gx0, &gy0);
      Derivatives8(dsrc + 2 * x + 16, sd, top, bottom, &gx1, &gy1);
      // Packing works within 128-bit halves: the permute puts the pixels back in order.
      __m256i gx = _mm256_permute4x64_epi64(_mm256_packs_epi32(gx0, gx1), 0xD8);
      __m256i gy = _mm256_permute4x64_epi64(_mm256_packs_epi32(gy0, gy1), 0xD8);
      if (x + 16 > win.w) {  // beyond the window: no weight
        const __m256i inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(int16_t(win.w - x)), lanes);
        gx = _mm256_and_si256(gx, inside);
        gy = _mm256_and_si256(gy, inside);
      }
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(xrow + x), gx);
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(yrow + x), gy);
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
  __m256 b1 = _mm256_setzero_ps(), b2 = _mm256_setzero_ps();
  for (int y = 0; y < win.h; ++y, src += sj) {
    const int16_t* irow = win.i.data() + y * win.stride;
    const int16_t* xrow = win.ix.data() + y * win.stride;
    const int16_t* yrow = win.iy.data() + y * win.stride;
    __m256i r1 = _mm256_setzero_si256(), r2 = _mm256_setzero_si256();
    for (int x = 0; x < win.stride; x += 16) {
      const __m256i diff = _mm256_sub_epi16(Bilinear16(src + x, sj, top, bottom),
                                            _mm256_loadu_si256(reinterpret_cast<const __m256i*>(irow + x)));
      r1 = _mm256_add_epi32(r1, _mm256_madd_epi16(diff, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(xrow + x))));
      r2 = _mm256_add_epi32(r2, _mm256_madd_epi16(diff, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(yrow + x))));
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

// One point through every level, coarse to fine; OpenCV's LKTrackerInvoker's rules.
void FollowPoint(const std::vector<Level>& levels, const Settings& s, cv::Point2f from, cv::Point2f* to,
                 uchar* status, Window& win) {
  const cv::Size ws = s.window;
  const cv::Point2f half((ws.width - 1) * 0.5f, (ws.height - 1) * 0.5f);
  const int top_level = int(levels.size()) - 1;
  cv::Point2f out = *to;
  for (int level = top_level; level >= 0; --level) {
    const Level& lv = levels[size_t(level)];
    const cv::Point2f prev = from * float(1. / (1 << level)) - half;
    cv::Point2f next = level == top_level ? out * float(1. / (1 << level)) : out * 2.f;
    out = next;
    const cv::Point ip(cvFloor(prev.x), cvFloor(prev.y));
    if (ip.x < -ws.width || ip.x >= lv.dI->cols || ip.y < -ws.height || ip.y >= lv.dI->rows) {
      if (level == 0) *status = 0;
      continue;
    }
    const Weights wi = WeightsAt(prev.x - float(ip.x), prev.y - float(ip.y));
    const uchar* isrc = lv.I->data + ptrdiff_t(ip.y) * ptrdiff_t(lv.I->step) + ip.x;
    const size_t dstep = lv.dI->step / sizeof(int16_t);
    const int16_t* dsrc = reinterpret_cast<const int16_t*>(lv.dI->data) + ptrdiff_t(ip.y) * ptrdiff_t(dstep) + 2 * ip.x;
    float A[3];
    const bool wide = s.vectorised && ip.x + win.stride + 1 <= lv.readable_i && ip.x + win.stride + 1 <= lv.readable_d;
    (wide ? TemplateAvx2 : TemplateScalar)(isrc, lv.I->step, dsrc, dstep, wi, win, A);
    const float A11 = A[0] * kFltScale, A12 = A[1] * kFltScale, A22 = A[2] * kFltScale;
    float D = A11 * A22 - A12 * A12;
    const float min_eigen =
        (A22 + A11 - std::sqrt((A11 - A22) * (A11 - A22) + 4.f * A12 * A12)) / float(2 * ws.width * ws.height);
    if (min_eigen < s.min_eigen || D < FLT_EPSILON) {
      if (level == 0) *status = 0;
      continue;
    }
    D = 1.f / D;
    next -= half;
    cv::Point2f last_delta;
    for (int j = 0; j < s.max_count; ++j) {
      const cv::Point in(cvFloor(next.x), cvFloor(next.y));
      if (in.x < -ws.width || in.x >= lv.J->cols || in.y < -ws.height || in.y >= lv.J->rows) {
        if (level == 0) *status = 0;
        break;
      }
      const Weights wj = WeightsAt(next.x - float(in.x), next.y - float(in.y));
      const uchar* jsrc = lv.J->data + ptrdiff_t(in.y) * ptrdiff_t(lv.J->step) + in.x;
      float b[2];
      const bool wide_j = s.vectorised && in.x + win.stride + 1 <= lv.readable_j;
      (wide_j ? MismatchAvx2 : MismatchScalar)(jsrc, lv.J->step, wj, win, b);
      const float b1 = b[0] * kFltScale, b2 = b[1] * kFltScale;
      const cv::Point2f delta(float((A12 * b2 - A22 * b1) * D), float((A12 * b1 - A11 * b2) * D));
      next += delta;
      out = next + half;
      if (delta.ddot(delta) <= s.epsilon2) break;
      if (j > 0 && std::abs(delta.x + last_delta.x) < 0.01 && std::abs(delta.y + last_delta.y) < 0.01) {
        out -= delta * 0.5f;  // oscillating: halfway
        break;
      }
      last_delta = delta;
    }
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

bool CpuHasAvx2() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
}

// The levels both pyramids hold with the borders the kernel reads; empty if they do not.
std::vector<Level> LevelsOf(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to, cv::Size window,
                            int levels) {
  std::vector<Level> out;
  const int have = std::min(int(from.size()), int(to.size())) / 2 - 1;
  const int border = std::max(window.width, window.height);
  for (int l = 0; l <= std::min(levels, have); ++l) {
    Level lv;
    lv.I = &from[size_t(2 * l)];
    lv.dI = &from[size_t(2 * l + 1)];
    lv.J = &to[size_t(2 * l)];
    if (lv.I->type() != CV_8UC1 || lv.J->type() != CV_8UC1 || lv.dI->type() != CV_16SC2 ||
        lv.dI->size() != lv.I->size() || !Bordered(*lv.I, border, &lv.readable_i) ||
        !Bordered(*lv.dI, border, &lv.readable_d) || !Bordered(*lv.J, border, &lv.readable_j))
      return {};
    out.push_back(lv);
  }
  return out;
}

void Follow(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to, const std::vector<cv::Point2f>& points,
            std::vector<cv::Point2f>* found, std::vector<uchar>* status, cv::Size window, int levels,
            const cv::TermCriteria& until, double min_eigen, bool vectorised) {
  const std::vector<Level> lv = LevelsOf(from, to, window, levels);
  if (lv.empty() || window.width > 64 || found->size() != points.size()) {  // not a pyramid this kernel reads
    cv::calcOpticalFlowPyrLK(from, to, points, *found, *status, cv::noArray(), window, levels, until,
                             cv::OPTFLOW_USE_INITIAL_FLOW, min_eigen);
    return;
  }
  Settings s;
  s.window = window;
  s.max_count = (until.type & cv::TermCriteria::COUNT) ? std::clamp(until.maxCount, 0, 100) : 30;
  const double eps = (until.type & cv::TermCriteria::EPS) ? std::clamp(until.epsilon, 0.0, 10.0) : 0.01;
  s.epsilon2 = eps * eps;
  s.min_eigen = float(min_eigen);
  s.vectorised = vectorised;
  status->assign(points.size(), 1);
  cv::parallel_for_(cv::Range(0, int(points.size())), [&](const cv::Range& r) {
    Window win(window);
    for (int i = r.start; i < r.end; ++i)
      FollowPoint(lv, s, points[size_t(i)], &(*found)[size_t(i)], &(*status)[size_t(i)], win);
  });
}

}  // namespace

bool LucasKanadeVectorised() { return CpuHasAvx2(); }

void FollowLucasKanade(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                       const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                       std::vector<uchar>* status, cv::Size window, int levels, const cv::TermCriteria& until,
                       double min_eigen) {
  if (!CpuHasAvx2()) {
    cv::calcOpticalFlowPyrLK(from, to, points, *found, *status, cv::noArray(), window, levels, until,
                             cv::OPTFLOW_USE_INITIAL_FLOW, min_eigen);
    return;
  }
  Follow(from, to, points, found, status, window, levels, until, min_eigen, true);
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
