#include "engine/ecc_translation.h"

#include <algorithm>
#include <cmath>

#include <immintrin.h>

#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "util/cpu_features.h"

namespace rolamos {
namespace {

constexpr int kMaxShift = 16;          // pixels a translation may leave the images by
constexpr int kPad = kMaxShift + 2;    // zeros around the input's planes: the taps beyond the shift
constexpr int kTail = 16;              // and a vector's width more on the right

// The input as OpenCV's ECC samples it: smoothed, its gradients (zero where the mask is), its
// mask eroded by the smoothing, each with a border of zeros (OpenCV's warp fills with zeros).
struct Planes {
  cv::Mat templ;                    // smoothed template, unpadded
  cv::Mat image, gx, gy, mask;      // padded, CV_32F (mask 0 or 1)
};

cv::Mat Padded(const cv::Mat& m) {
  cv::Mat out;
  cv::copyMakeBorder(m, out, kPad, kPad, kPad, kPad + kTail, cv::BORDER_CONSTANT, cv::Scalar(0));
  return out;
}

// findTransformECC's preparation with gaussFiltSize 3, step by step.
Planes Prepare(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask) {
  Planes p;
  cv::GaussianBlur(templ, p.templ, cv::Size(3, 3), 0, 0);
  cv::Mat valid;
  if (input_mask.empty()) valid = cv::Mat::ones(input.size(), CV_8U);
  else cv::threshold(input_mask, valid, 0, 1, cv::THRESH_BINARY);
  // The mask smoothed like the images and kept where it stays above 0.95.
  cv::Mat valid_f;
  valid.convertTo(valid_f, CV_32F);
  cv::GaussianBlur(valid_f, valid_f, cv::Size(3, 3), 0, 0);
  valid_f *= 0.5 / 0.95;
  valid_f.convertTo(valid, CV_8U);
  valid.convertTo(valid_f, CV_32F);
  cv::Mat image, gx, gy;
  cv::GaussianBlur(input, image, cv::Size(3, 3), 0, 0);
  const cv::Matx13f derivative(-0.5f, 0.0f, 0.5f);
  cv::filter2D(image, gx, -1, derivative);
  cv::filter2D(image, gy, -1, derivative.t());
  p.image = Padded(image);
  p.gx = Padded(gx.mul(valid_f));
  p.gy = Padded(gy.mul(valid_f));
  p.mask = Padded(valid_f);
  return p;
}

// One step's sums over the template's pixels (m: the sampled mask, t: template, i: input, g:
// its gradients).
struct Sums {
  double n = 0, i = 0, ii = 0, t = 0, tt = 0, ti = 0;  // masked
  double xx = 0, xy = 0, yy = 0;                       // the Hessian's, over every pixel
  double xi = 0, yi = 0, xm = 0, ym = 0, xmt = 0, ymt = 0;
};

// Where a step samples: the bilinear taps' offset and weights, the nearest pixel's offset, where
// OpenCV's warpAffine takes them for a shift t: positions in 1/1024 pixel, rounded to 1/32 for
// the bilinear taps and to whole pixels for the nearest. Exact positions find the same optimum
// within that 1/32 (tests), but each step then differs a little from OpenCV's, and on chain-bound
// surveys (small-degraded) any such difference, even OpenCV's own ECC at a 0.04 % different
// scale, moves a draw's per-patch error by up to several pixels either way; sampled where OpenCV
// samples, the steps are OpenCV's up to the rounding of the sums.
struct Sampling {
  int fx, fy, rx, ry;
  float ax, ay;
  explicit Sampling(cv::Point2f s) {
    Taps(s.x, &fx, &ax, &rx);
    Taps(s.y, &fy, &ay, &ry);
  }
  static void Taps(float t, int* whole, float* fraction, int* nearest) {
    const int fixed = static_cast<int>(std::lrint(double(t) * 1024));
    const int q = (fixed + 16) >> 5;  // 1/32 pixel, rounded
    *whole = q >> 5;
    *fraction = float(q & 31) * (1.f / 32);
    *nearest = (fixed + 512) >> 10;
  }
  bool Inside() const {
    return std::max({std::abs(fx), std::abs(fy), std::abs(rx), std::abs(ry)}) <= kMaxShift;
  }
};

inline float Bilinear(const float* top, const float* bottom, float ax, float ay) {
  const float upper = top[0] + ax * (top[1] - top[0]);
  const float lower = bottom[0] + ax * (bottom[1] - bottom[0]);
  return upper + ay * (lower - upper);
}

// Template row y and the rows a step samples for it: each plane's two rows of bilinear taps from
// the first one's column, the mask's nearest row.
struct Row {
  const float *t, *i0, *i1, *x0, *x1, *y0, *y1, *m;
  Row(const Planes& p, const Sampling& s, int y) {
    const int top = y + s.fy + kPad, left = s.fx + kPad;
    t = p.templ.ptr<float>(y);
    i0 = p.image.ptr<float>(top) + left, i1 = p.image.ptr<float>(top + 1) + left;
    x0 = p.gx.ptr<float>(top) + left, x1 = p.gx.ptr<float>(top + 1) + left;
    y0 = p.gy.ptr<float>(top) + left, y1 = p.gy.ptr<float>(top + 1) + left;
    m = p.mask.ptr<float>(y + s.ry + kPad) + s.rx + kPad;
  }
};

Sums SumScalar(const Planes& p, const Sampling& s) {
  Sums r;
  for (int y = 0; y < p.templ.rows; ++y) {
    const auto [t, i0, i1, x0, x1, y0, y1, m] = Row(p, s, y);
    for (int x = 0; x < p.templ.cols; ++x) {
      const double i = Bilinear(i0 + x, i1 + x, s.ax, s.ay), gx = Bilinear(x0 + x, x1 + x, s.ax, s.ay),
                   gy = Bilinear(y0 + x, y1 + x, s.ax, s.ay), mm = m[x], mt = mm * t[x];
      r.n += mm;
      r.i += mm * i;
      r.ii += mm * i * i;
      r.t += mt;
      r.tt += mt * t[x];
      r.ti += mt * i;
      r.xx += gx * gx;
      r.xy += gx * gy;
      r.yy += gy * gy;
      r.xi += gx * i;
      r.yi += gy * i;
      r.xm += gx * mm;
      r.ym += gy * mm;
      r.xmt += gx * mt;
      r.ymt += gy * mt;
    }
  }
  return r;
}

__attribute__((target("avx512f"))) inline __m512 BilinearAvx512(const float* top, const float* bottom, __m512 ax,
                                                                 __m512 ay) {
  const __m512 a = _mm512_loadu_ps(top), b = _mm512_loadu_ps(top + 1);
  const __m512 c = _mm512_loadu_ps(bottom), d = _mm512_loadu_ps(bottom + 1);
  const __m512 upper = _mm512_fmadd_ps(ax, _mm512_sub_ps(b, a), a);
  const __m512 lower = _mm512_fmadd_ps(ax, _mm512_sub_ps(d, c), c);
  return _mm512_fmadd_ps(ay, _mm512_sub_ps(lower, upper), upper);
}

// Sixteen pixels at a time; each row's sums in float (at most a few hundred terms a lane), the
// rows' in double.
__attribute__((target("avx512f"))) Sums SumAvx512(const Planes& p, const Sampling& s) {
  enum { kN, kI, kII, kT, kTT, kTI, kXX, kXY, kYY, kXI, kYI, kXM, kYM, kXMT, kYMT, kCount };
  double total[kCount] = {};
  const __m512 ax = _mm512_set1_ps(s.ax), ay = _mm512_set1_ps(s.ay);
  const int cols = p.templ.cols;
  for (int y = 0; y < p.templ.rows; ++y) {
    const auto [t, i0, i1, x0, x1, y0, y1, m] = Row(p, s, y);
    __m512 acc[kCount];
    for (auto& a : acc) a = _mm512_setzero_ps();
    for (int x = 0; x < cols; x += 16) {
      const __mmask16 lanes = cols - x >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (cols - x)) - 1);
      const __m512 i = _mm512_maskz_mov_ps(lanes, BilinearAvx512(i0 + x, i1 + x, ax, ay));
      const __m512 gx = _mm512_maskz_mov_ps(lanes, BilinearAvx512(x0 + x, x1 + x, ax, ay));
      const __m512 gy = _mm512_maskz_mov_ps(lanes, BilinearAvx512(y0 + x, y1 + x, ax, ay));
      const __m512 mm = _mm512_maskz_loadu_ps(lanes, m + x), tv = _mm512_maskz_loadu_ps(lanes, t + x);
      const __m512 mt = _mm512_mul_ps(mm, tv), mi = _mm512_mul_ps(mm, i);
      acc[kN] = _mm512_add_ps(acc[kN], mm);
      acc[kI] = _mm512_add_ps(acc[kI], mi);
      acc[kII] = _mm512_fmadd_ps(mi, i, acc[kII]);
      acc[kT] = _mm512_add_ps(acc[kT], mt);
      acc[kTT] = _mm512_fmadd_ps(mt, tv, acc[kTT]);
      acc[kTI] = _mm512_fmadd_ps(mt, i, acc[kTI]);
      acc[kXX] = _mm512_fmadd_ps(gx, gx, acc[kXX]);
      acc[kXY] = _mm512_fmadd_ps(gx, gy, acc[kXY]);
      acc[kYY] = _mm512_fmadd_ps(gy, gy, acc[kYY]);
      acc[kXI] = _mm512_fmadd_ps(gx, i, acc[kXI]);
      acc[kYI] = _mm512_fmadd_ps(gy, i, acc[kYI]);
      acc[kXM] = _mm512_fmadd_ps(gx, mm, acc[kXM]);
      acc[kYM] = _mm512_fmadd_ps(gy, mm, acc[kYM]);
      acc[kXMT] = _mm512_fmadd_ps(gx, mt, acc[kXMT]);
      acc[kYMT] = _mm512_fmadd_ps(gy, mt, acc[kYMT]);
    }
    for (int k = 0; k < kCount; ++k) total[k] += _mm512_reduce_add_ps(acc[k]);
  }
  Sums r;
  r.n = total[kN], r.i = total[kI], r.ii = total[kII], r.t = total[kT], r.tt = total[kTT], r.ti = total[kTI];
  r.xx = total[kXX], r.xy = total[kXY], r.yy = total[kYY], r.xi = total[kXI], r.yi = total[kYI];
  r.xm = total[kXM], r.ym = total[kYM], r.xmt = total[kXMT], r.ymt = total[kYMT];
  return r;
}

// One Gauss-Newton step of ECC from the sums (the paper's eq. for a translation's two
// parameters): sets the correlation, moves the shift, or says why it cannot.
bool Step(const Sums& s, double* rho, cv::Point2f* shift, std::string* failure) {
  if (s.n < 1) {
    *failure = "no valid input pixel under the template";
    return false;
  }
  const double im = s.i / s.n, tm = s.t / s.n;
  const double image_norm2 = s.n * std::max(s.ii / s.n - im * im, 0.0);
  const double templ_norm2 = s.n * std::max(s.tt / s.n - tm * tm, 0.0);
  // The template and the input zero-mean where the mask is; outside it the input keeps its
  // values in the projections (as OpenCV subtracts the mean under the mask only).
  const double correlation = s.ti - tm * s.i - im * s.t + s.n * tm * im;
  *rho = correlation / std::sqrt(image_norm2 * templ_norm2);
  if (!(image_norm2 > 0 && templ_norm2 > 0) || !std::isfinite(*rho)) {
    *failure = "the correlation is not a number (a flat image)";
    return false;
  }
  const double det = s.xx * s.yy - s.xy * s.xy;
  if (!(det > 0)) {
    *failure = "the input has no gradient under the template";
    return false;
  }
  const cv::Matx22d inverse(s.yy / det, -s.xy / det, -s.xy / det, s.xx / det);
  const cv::Vec2d image(s.xi - im * s.xm, s.yi - im * s.ym), templ(s.xmt - tm * s.xm, s.ymt - tm * s.ym);
  const cv::Vec2d image_h = inverse * image;
  const double lambda_n = image_norm2 - image.dot(image_h);
  const double lambda_d = correlation - templ.dot(image_h);
  if (lambda_d <= 0) {
    *failure = "the step would lower the correlation (the images may not overlap)";
    return false;
  }
  const cv::Vec2d delta = inverse * ((lambda_n / lambda_d) * templ - image);
  *shift += cv::Point2f(float(delta[0]), float(delta[1]));  // OpenCV's warp matrix is float
  return true;
}

EccTranslation Find(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask, cv::Point2d start,
                    int iterations, double epsilon, bool vector) {
  if (templ.type() != CV_32F || input.type() != CV_32F || templ.size() != input.size() ||
      (!input_mask.empty() && (input_mask.type() != CV_8U || input_mask.size() != input.size())))
    Fail("ECC translation", "the template (" + cv::typeToString(templ.type()) + ", " + std::to_string(templ.cols) +
                                " x " + std::to_string(templ.rows) + ") and input (" +
                                cv::typeToString(input.type()) + ", " + std::to_string(input.cols) + " x " +
                                std::to_string(input.rows) + ") must be 32-bit float of one size, the mask 8-bit");
  EccTranslation r;
  cv::Point2f shift(start);
  r.shift = shift;
  const Planes planes = Prepare(templ, input, input_mask);
  double rho = -1, last = -epsilon;
  for (int k = 1; k <= iterations && std::abs(rho - last) >= epsilon; ++k) {
    const Sampling s(shift);
    if (!s.Inside()) {
      r.failure = "the shift left the images by more than " + std::to_string(kMaxShift) + " pixels";
      return r;
    }
    const Sums sums = vector ? SumAvx512(planes, s) : SumScalar(planes, s);
    last = rho;
    if (!Step(sums, &rho, &shift, &r.failure)) return r;
    r.shift = shift;
    r.iterations = k;
  }
  r.correlation = rho;
  r.ok = true;
  return r;
}

}  // namespace

EccTranslation FindEccTranslation(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask,
                                  cv::Point2d start, int iterations, double epsilon) {
  return Find(templ, input, input_mask, start, iterations, epsilon, CpuHasAvx512());
}

namespace internal {
EccTranslation FindEccTranslationScalar(const cv::Mat& templ, const cv::Mat& input, const cv::Mat& input_mask,
                                        cv::Point2d start, int iterations, double epsilon) {
  return Find(templ, input, input_mask, start, iterations, epsilon, false);
}
}  // namespace internal

}  // namespace rolamos
