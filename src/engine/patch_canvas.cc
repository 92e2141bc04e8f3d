#include "engine/patch_canvas.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <immintrin.h>

#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "engine/bilinear_warp.h"
#include "engine/channel_shuffle.h"
#include "engine/perspective_warp.h"
#include "util/cpu_features.h"
#include "util/homography.h"

namespace rolamos {

namespace {

cv::Rect Enclosing(const cv::Rect2d& r) {
  const int x0 = static_cast<int>(std::floor(r.x)), y0 = static_cast<int>(std::floor(r.y));
  const int x1 = static_cast<int>(std::ceil(r.x + r.width)), y1 = static_cast<int>(std::ceil(r.y + r.height));
  return cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
}

int FloorDiv(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

}  // namespace

PatchCanvas::PatchCanvas(long long pixel_budget, double scale, bool reduced)
    : budget_(pixel_budget), scale_(scale), reduced_(reduced) {
  CV_Assert(scale > 0 && scale <= 1);
}

cv::Matx33d PatchCanvas::ToCanvas() const {
  const double c = scale_;
  return cv::Matx33d(c, 0, 0.5 * (c - 1), 0, c, 0.5 * (c - 1), 0, 0, 1);
}

cv::Rect2d PatchCanvas::FrameBounds(const cv::Matx33d& H, cv::Size frame) {
  return WarpedBounds(H, frame);
}

cv::Rect PatchCanvas::SourceRect(const cv::Matx33d& frame_to_patch, const cv::Rect& rect, cv::Size frame) {
  const cv::Matx33d back = frame_to_patch.inv();
  double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
  for (const cv::Point2d p : {cv::Point2d(rect.x, rect.y), cv::Point2d(rect.br().x, rect.y),
                              cv::Point2d(rect.x, rect.br().y), cv::Point2d(rect.br().x, rect.br().y)}) {
    const cv::Vec3d q = back * cv::Vec3d(p.x, p.y, 1);
    if (!(q[2] > 1e-9)) return cv::Rect(cv::Point(), frame);
    x0 = std::min(x0, q[0] / q[2]);
    y0 = std::min(y0, q[1] / q[2]);
    x1 = std::max(x1, q[0] / q[2]);
    y1 = std::max(y1, q[1] / q[2]);
  }
  constexpr double kMargin = 3;
  const cv::Rect2d wanted(x0 - kMargin, y0 - kMargin, x1 - x0 + 2 * kMargin, y1 - y0 + 2 * kMargin);
  const cv::Rect2d clipped = wanted & cv::Rect2d(0, 0, frame.width, frame.height);
  if (clipped.empty()) return cv::Rect();
  const int left = static_cast<int>(std::floor(clipped.x)), top = static_cast<int>(std::floor(clipped.y));
  return cv::Rect(left, top, static_cast<int>(std::ceil(clipped.br().x)) - left,
                  static_cast<int>(std::ceil(clipped.br().y)) - top) &
         cv::Rect(cv::Point(), frame);
}

bool PatchCanvas::Fits(const cv::Rect2d& bounds) const {
  if (!std::isfinite(bounds.x) || !std::isfinite(bounds.y) || !std::isfinite(bounds.width) ||
      !std::isfinite(bounds.height) || bounds.width > 1e8 || bounds.height > 1e8)
    return false;
  const cv::Rect need = data_.empty() ? Enclosing(bounds) : (data_ | Enclosing(bounds));
  return static_cast<long long>(need.width) * need.height <= budget_;
}

namespace {

// Whether any pixel of `part` (BGRW) carries weight: the ROI's empty corners need no blocks.
template <typename Px>
bool AnyWeight(const cv::Mat& part) {
  for (int y = 0; y < part.rows; ++y) {
    const Px* p = part.ptr<Px>(y);
    for (int x = 0; x < part.cols; ++x)
      if (p[x][3]) return true;
  }
  return false;
}

}  // namespace

cv::Mat PatchCanvas::Interleave(const cv::Mat& frame, const cv::Mat& code) {
  CV_Assert((frame.type() == CV_8UC3 || frame.type() == CV_16UC3) && code.type() == CV_8U &&
            code.size() == frame.size());
  if (frame.depth() == CV_8U) return InterleaveBgrAnd(frame, code);
  cv::Mat wide;
  code.convertTo(wide, CV_16U);
  cv::Mat bgrw(frame.size(), CV_16UC4);
  const cv::Mat in[] = {frame, wide};
  const int from_to[] = {0, 0, 1, 1, 2, 2, 3, 3};
  cv::mixChannels(in, 2, &bgrw, 1, from_to, 4);
  return bgrw;
}

namespace {

// One row of a frame's 8-bit channels times the colour correction (one factor per channel, or
// none) and `scale`, rounded and saturated to 16 bits, as a flat run of values.
void CorrectRowScalar(const uchar* p, const float* c, float s, int n, ushort* out) {
  for (int i = 0; i < n; ++i) out[i] = cv::saturate_cast<ushort>(c ? float(p[i]) * c[i] * s : float(p[i]) * s);
}

__attribute__((target("avx2"))) void CorrectRowAvx2(const uchar* p, const float* c, float s, int n, ushort* out) {
  const __m256 scale = _mm256_set1_ps(s);
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    __m256 v = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + i))));
    if (c) v = _mm256_mul_ps(v, _mm256_loadu_ps(c + i));
    // Rounded to nearest as cvRound; past 65535 saturated by the pack (values stay far below 2^31).
    const __m256i q = _mm256_cvtps_epi32(_mm256_mul_ps(v, scale));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                     _mm_packus_epi32(_mm256_castsi256_si128(q), _mm256_extracti128_si256(q, 1)));
  }
  CorrectRowScalar(p + i, c ? c + i : nullptr, s, n - i, out + i);
}

// Pixels [0, n) of a row: corrected values (B, G, R, ...) and codes into (B, G, R, code) words.
void InterleaveRowScalar(const ushort* row, const uchar* code, int n, cv::Vec4w* out) {
  for (int x = 0; x < n; ++x) out[x] = cv::Vec4w(row[3 * x], row[3 * x + 1], row[3 * x + 2], code[x]);
}

// Eight pixels at a time: 24 values and 8 codes into 32 words by one permute.
__attribute__((target("avx512f,avx512bw"))) void InterleaveRowAvx512(const ushort* row, const uchar* code, int n,
                                                                    cv::Vec4w* out) {
  alignas(64) uint16_t order[32];
  for (int p = 0; p < 8; ++p)
    for (int c = 0; c < 4; ++c) order[4 * p + c] = static_cast<uint16_t>(c < 3 ? 3 * p + c : 32 + p);
  const __m512i idx = _mm512_load_si512(order);
  int x = 0;
  for (; x + 8 <= n; x += 8) {
    const __m512i values = _mm512_maskz_loadu_epi16(0xFFFFFF, row + 3 * x);
    const __m512i codes =
        _mm512_zextsi128_si512(_mm_cvtepu8_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(code + x))));
    _mm512_storeu_si512(out + x, _mm512_permutex2var_epi16(values, idx, codes));
  }
  InterleaveRowScalar(row + 3 * x, code + x, n - x, out + x);
}

}  // namespace

cv::Mat PatchCanvas::InterleaveDeep(const cv::Mat& frame, const cv::Mat& colour, double scale, const cv::Mat& code) {
  CV_Assert(frame.type() == CV_8UC3 && code.type() == CV_8U && code.size() == frame.size());
  CV_Assert(colour.empty() || (colour.type() == CV_32FC3 && colour.size() == frame.size()));
  const bool avx2 = CpuHasAvx2(), bw = CpuHasAvx512Bw();
  cv::Mat bgrw(frame.size(), CV_16UC4);
  const float s = static_cast<float>(scale);
  cv::parallel_for_(cv::Range(0, frame.rows), [&](const cv::Range& range) {
    std::vector<ushort> row(3 * static_cast<size_t>(frame.cols));
    for (int y = range.start; y < range.end; ++y) {
      const float* c = colour.empty() ? nullptr : colour.ptr<float>(y);
      (avx2 ? CorrectRowAvx2 : CorrectRowScalar)(frame.ptr<uchar>(y), c, s, 3 * frame.cols, row.data());
      (bw ? InterleaveRowAvx512 : InterleaveRowScalar)(row.data(), code.ptr<uchar>(y), frame.cols,
                                                       bgrw.ptr<cv::Vec4w>(y));
    }
  });
  return bgrw;
}

void PatchCanvas::Add(const cv::Mat& frame, const FeatherCode& weights, const cv::Matx33d& frame_to_patch,
                      const cv::Rect& clip) {
  if (scale_ == 1) return AddAtScale(Interleave(frame, weights.code), weights.weight, frame_to_patch, frame.size(), clip);
  // Reduced first (area average: no aliasing, a smaller warp), then interleaved: area averaging
  // goes channel by channel, so this is what reducing the interleaved frame gives, with a
  // quarter of the pixels to interleave.
  cv::Mat small, small_code;
  ResizeArea(frame, small, scale_);
  ResizeArea(weights.code, small_code, scale_);
  AddAtScale(Interleave(small, small_code), weights.weight, frame_to_patch, frame.size(), clip);
}

void PatchCanvas::AddInterleaved(const cv::Mat& bgrw, const std::array<float, 256>& weight,
                                 const cv::Matx33d& frame_to_patch, const cv::Rect& clip) {
  CV_Assert(scale_ == 1);  // the patch writer's full-resolution bands
  AddAtScale(bgrw, weight, frame_to_patch, bgrw.size(), clip);
}

namespace {

// Whether the convex quadrilateral `quad` meets the pixels of `r` (as the square extents of its
// pixel centres), by separating axes: the rectangle's two and the quadrilateral's four.
bool QuadMeets(const std::array<cv::Point2d, 4>& quad, const cv::Rect& r) {
  const std::array<cv::Point2d, 4> box = {cv::Point2d(r.x - 0.5, r.y - 0.5), cv::Point2d(r.br().x - 0.5, r.y - 0.5),
                                          cv::Point2d(r.br().x - 0.5, r.br().y - 0.5),
                                          cv::Point2d(r.x - 0.5, r.br().y - 0.5)};
  const auto apart = [](const std::array<cv::Point2d, 4>& a, const std::array<cv::Point2d, 4>& b, cv::Point2d axis) {
    double a0 = 1e300, a1 = -1e300, b0 = 1e300, b1 = -1e300;
    for (const auto& p : a) a0 = std::min(a0, axis.dot(p)), a1 = std::max(a1, axis.dot(p));
    for (const auto& p : b) b0 = std::min(b0, axis.dot(p)), b1 = std::max(b1, axis.dot(p));
    return a1 < b0 || b1 < a0;
  };
  if (apart(quad, box, {1, 0}) || apart(quad, box, {0, 1})) return false;
  for (size_t i = 0; i < 4; ++i) {
    const cv::Point2d edge = quad[(i + 1) % 4] - quad[i];
    if (apart(quad, box, {-edge.y, edge.x})) return false;
  }
  return true;
}

}  // namespace

void PatchCanvas::AddAtScale(const cv::Mat& bgrw, const std::array<float, 256>& weight,
                             const cv::Matx33d& frame_to_patch, cv::Size frame, const cv::Rect& clip) {
  // 16-bit frames (colour-corrected, kDeepScale per grey level) only where nothing is reduced.
  const bool deep = bgrw.type() == CV_16UC4;
  CV_Assert(bgrw.type() == CV_8UC4 || (deep && scale_ == 1 && !reduced_));
  CV_Assert(clip.empty() || scale_ == 1);
  cv::Rect patch_roi = Enclosing(FrameBounds(frame_to_patch, frame));
  if (!clip.empty()) patch_roi &= clip;
  if (patch_roi.empty()) return;
  data_ = data_.empty() ? patch_roi : (data_ | patch_roi);
  // Colour and weight code travel together in one 4-channel warp: frame -> canvas pixel = H.
  // Edge pixels repeat past the frame (colours are never mixed with black) while the weight
  // code, 0 on the frame's outer ring, fades to nothing.
  cv::Matx33d H = ToCanvas() * frame_to_patch;
  if (scale_ < 1) {
    const double c = scale_;
    const cv::Matx33d S(c, 0, 0.5 * (c - 1), 0, c, 0.5 * (c - 1), 0, 0, 1);
    H = H * S.inv();
  }
  cv::Rect roi = Enclosing(FrameBounds(H, bgrw.size()));
  if (!clip.empty()) roi &= clip;  // canvas pixels are patch coordinates at scale 1
  if (roi.empty()) return;
  cdata_ = cdata_.empty() ? roi : (cdata_ | roi);
  if (reduced_) {
    // OpenCV's warp's pixels on the working canvas, which frames are registered against (ECC,
    // recovery): the AVX2 interpolation of WarpAccumulate differs from it by 0.03 grey levels on
    // average (rounding), yet with it the placements moved on most degraded surveys of the
    // spread, small-degraded from 0.74 to 1.07 px. The engine's accuracy was measured with
    // OpenCV's pixels, which WarpPerspectiveLinear gives.
    cv::Mat warped;
    WarpPerspectiveLinear(bgrw, warped, cv::Matx33d(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1) * H, roi.size(),
                          cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    AddReduced(warped, weight, roi);
  } else {
    AddBlended(bgrw, weight, H, roi);
  }
}

PatchCanvas::Block& PatchCanvas::BlockAt(int bx, int by) {
  Block& b = blocks_[Key(bx, by)];
  if (b.sum.empty()) {
    b.sum = cv::Mat::zeros(kBlock, kBlock, CV_32FC3);
    b.weight = cv::Mat::zeros(kBlock, kBlock, CV_32F);
    if (reduced_) {
      b.small_sum = cv::Mat::zeros(kBlock / kMirror, kBlock / kMirror, CV_32FC3);
      b.small_weight = cv::Mat::zeros(kBlock / kMirror, kBlock / kMirror, CV_32F);
    }
  }
  return b;
}

void PatchCanvas::AddBlended(const cv::Mat& bgrw, const std::array<float, 256>& weight, const cv::Matx33d& H,
                             const cv::Rect& roi) {
  // The blocks the frame's quadrilateral meets (created here, on one thread), then each blended
  // into straight from the frame, in parallel: no warped copy of the frame in between.
  std::array<cv::Point2d, 4> quad;
  const cv::Point2d corners[] = {{-0.5, -0.5}, {bgrw.cols - 0.5, -0.5}, {bgrw.cols - 0.5, bgrw.rows - 0.5}, {-0.5, bgrw.rows - 0.5}};
  bool convex = true;  // a corner behind the camera: the quadrilateral means nothing, take every block
  for (size_t i = 0; i < 4; ++i) {
    const cv::Vec3d q = H * cv::Vec3d(corners[i].x, corners[i].y, 1);
    convex = convex && q[2] > 0;
    quad[i] = cv::Point2d(q[0] / q[2], q[1] / q[2]);
  }
  std::vector<std::pair<cv::Rect, Block*>> parts;  // (the frame's pixels in the block, the block)
  for (int by = FloorDiv(roi.y, kBlock); by <= FloorDiv(roi.y + roi.height - 1, kBlock); ++by)
    for (int bx = FloorDiv(roi.x, kBlock); bx <= FloorDiv(roi.x + roi.width - 1, kBlock); ++bx) {
      const cv::Rect overlap = cv::Rect(bx * kBlock, by * kBlock, kBlock, kBlock) & roi;
      if (!overlap.empty() && (!convex || QuadMeets(quad, overlap))) parts.emplace_back(overlap, &BlockAt(bx, by));
    }
  const float unit = bgrw.depth() == CV_16U ? 1.0f / kDeepScale : 1.0f;
  cv::parallel_for_(cv::Range(0, static_cast<int>(parts.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const cv::Rect& overlap = parts[static_cast<size_t>(i)].first;
      Block& b = *parts[static_cast<size_t>(i)].second;
      const cv::Rect in_block(overlap.x - FloorDiv(overlap.x, kBlock) * kBlock,
                              overlap.y - FloorDiv(overlap.y, kBlock) * kBlock, overlap.width, overlap.height);
      cv::Mat sum = b.sum(in_block), weight_sum = b.weight(in_block);
      WarpAccumulate(bgrw, cv::Matx33d(1, 0, -overlap.x, 0, 1, -overlap.y, 0, 0, 1) * H, weight, unit, sum, weight_sum);
    }
  });
}

namespace {

// One row of the working canvas's accumulation: pixels [0, n) of `px` (BGRW) into the sums from
// column `col` of a block, and into the 2 x 2 means' row: weight[code] x colour and weight[code]
// (code 0 adds nothing), each a quarter into its cell.
void AddReducedRowScalar(const cv::Vec4b* px, int n, int col, const float* table, cv::Vec3f* acc, float* wsum,
                         cv::Vec3f* small, float* small_w) {
  constexpr float kCell = 0.25f;
  for (int x = 0; x < n; ++x) {
    if (!px[x][3]) continue;
    const float a = table[px[x][3]];
    const cv::Vec3f c(a * px[x][0], a * px[x][1], a * px[x][2]);
    acc[x] += c;
    wsum[x] += a;
    const int cell = (col + x) / 2;
    small[cell] += c * kCell;
    small_w[cell] += a * kCell;
  }
}

// The same sixteen pixels (eight cells) at a time with AVX-512 from an even column: each sum
// gets the same products in the same order (a cell its even pixel's, then its odd one's; code 0
// adds +0, which leaves a sum of non-negative values as it was).
struct ReducedLayout {
  alignas(64) int32_t bg[3][16], r[3][16];    // B, G then R into interleaved BGR, 48 values
  alignas(64) int32_t even[16], odd[16];       // a vector's even and odd lanes into lanes 0..7
  alignas(64) int32_t cell_bg[2][16], cell_r[2][16];  // 8 cells' B, G, R interleaved, 24 values
  ReducedLayout() {
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 16; ++i) {
        const int v = 16 * j + i, p = v / 3, c = v % 3;
        bg[j][i] = c == 0 ? p : 16 + p;  // b from the first source, g from the second
        r[j][i] = p;
      }
    for (int i = 0; i < 16; ++i) {
      even[i] = 2 * (i % 8);
      odd[i] = 2 * (i % 8) + 1;
    }
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 16; ++i) {
        const int v = 16 * j + i, p = (v / 3) % 8, c = v % 3;
        cell_bg[j][i] = c == 0 ? p : 16 + p;
        cell_r[j][i] = p;
      }
  }
};

// Lanes of an interleaved vector j (16 values) that hold R: value 16 j + i with (16 j + i) % 3 == 2.
constexpr __mmask16 RedLanes(int j) {
  __mmask16 m = 0;
  for (int i = 0; i < 16; ++i)
    if ((16 * j + i) % 3 == 2) m = static_cast<__mmask16>(m | (1u << i));
  return m;
}

__attribute__((target("avx512f"))) inline __m512 Interleaved(const int32_t* bg, const int32_t* r, __mmask16 red,
                                                             __m512 b, __m512 g, __m512 rr) {
  const __m512 two = _mm512_permutex2var_ps(b, _mm512_load_si512(bg), g);
  return _mm512_mask_permutexvar_ps(two, red, _mm512_load_si512(r), rr);
}

__attribute__((target("avx512f"))) void AddReducedRowAvx512(const cv::Vec4b* px, int n, int col, const float* table,
                                                            cv::Vec3f* acc, float* wsum, cv::Vec3f* small,
                                                            float* small_w) {
  static const ReducedLayout lay;
  int x = 0;
  if ((col & 1) && n > 0) {  // an odd first column: its cell's even pixel is not in this segment
    AddReducedRowScalar(px, 1, col, table, acc, wsum, small, small_w);
    x = 1;
  }
  const __m512i byte = _mm512_set1_epi32(0xFF), zero = _mm512_setzero_si512();
  const __m512 quarter = _mm512_set1_ps(0.25f);
  for (; x + 16 <= n; x += 16) {
    const __m512i v = _mm512_loadu_si512(px + x);
    const __m512i code = _mm512_srli_epi32(v, 24);
    const __mmask16 used = _mm512_cmpneq_epi32_mask(code, zero);
    const __m512 a = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), used, code, table, 4);
    const __m512 cb = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(v, byte)));
    const __m512 cg = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(v, 8), byte)));
    const __m512 cr = _mm512_mul_ps(a, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(v, 16), byte)));
    float* s = acc[x].val;
    _mm512_storeu_ps(s, _mm512_add_ps(_mm512_loadu_ps(s), Interleaved(lay.bg[0], lay.r[0], RedLanes(0), cb, cg, cr)));
    _mm512_storeu_ps(s + 16,
                     _mm512_add_ps(_mm512_loadu_ps(s + 16), Interleaved(lay.bg[1], lay.r[1], RedLanes(1), cb, cg, cr)));
    _mm512_storeu_ps(s + 32,
                     _mm512_add_ps(_mm512_loadu_ps(s + 32), Interleaved(lay.bg[2], lay.r[2], RedLanes(2), cb, cg, cr)));
    _mm512_storeu_ps(wsum + x, _mm512_add_ps(_mm512_loadu_ps(wsum + x), a));
    // The cells: each quarter, even pixels then odd ones.
    const __m512i even = _mm512_load_si512(lay.even), odd = _mm512_load_si512(lay.odd);
    const __m512 qb = _mm512_mul_ps(cb, quarter), qg = _mm512_mul_ps(cg, quarter), qr = _mm512_mul_ps(cr, quarter);
    const __m512 qa = _mm512_mul_ps(a, quarter);
    const __m512 eb = _mm512_permutexvar_ps(even, qb), eg = _mm512_permutexvar_ps(even, qg),
                 er = _mm512_permutexvar_ps(even, qr);
    const __m512 ob = _mm512_permutexvar_ps(odd, qb), og = _mm512_permutexvar_ps(odd, qg),
                 orr = _mm512_permutexvar_ps(odd, qr);
    float* c = small[(col + x) / 2].val;
    const __mmask16 first8 = 0xFF;
    const __m512 e0 = Interleaved(lay.cell_bg[0], lay.cell_r[0], RedLanes(0), eb, eg, er);
    const __m512 e1 = Interleaved(lay.cell_bg[1], lay.cell_r[1], RedLanes(1), eb, eg, er);
    const __m512 o0 = Interleaved(lay.cell_bg[0], lay.cell_r[0], RedLanes(0), ob, og, orr);
    const __m512 o1 = Interleaved(lay.cell_bg[1], lay.cell_r[1], RedLanes(1), ob, og, orr);
    _mm512_storeu_ps(c, _mm512_add_ps(_mm512_add_ps(_mm512_loadu_ps(c), e0), o0));
    _mm512_mask_storeu_ps(c + 16, first8,
                          _mm512_add_ps(_mm512_add_ps(_mm512_maskz_loadu_ps(first8, c + 16), e1), o1));
    float* w = small_w + (col + x) / 2;
    _mm512_mask_storeu_ps(w, first8,
                          _mm512_add_ps(_mm512_add_ps(_mm512_maskz_loadu_ps(first8, w), _mm512_permutexvar_ps(even, qa)),
                                        _mm512_permutexvar_ps(odd, qa)));
  }
  AddReducedRowScalar(px + x, n - x, col + x, table, acc + x, wsum + x, small, small_w);
}

}  // namespace

void PatchCanvas::AddReduced(const cv::Mat& warped, const std::array<float, 256>& weight, const cv::Rect& roi) {
  // The blocks this frame touches (created here, on one thread), then filled in parallel.
  const int bx0 = FloorDiv(roi.x, kBlock), by0 = FloorDiv(roi.y, kBlock);
  const int bx1 = FloorDiv(roi.x + roi.width - 1, kBlock), by1 = FloorDiv(roi.y + roi.height - 1, kBlock);
  std::vector<std::pair<cv::Rect, Block*>> parts;  // (block rect in canvas pixels, block)
  for (int by = by0; by <= by1; ++by) {
    for (int bx = bx0; bx <= bx1; ++bx) {
      const cv::Rect block_rect(bx * kBlock, by * kBlock, kBlock, kBlock);
      const cv::Rect overlap = block_rect & roi;
      if (overlap.empty() || !AnyWeight<cv::Vec4b>(warped(overlap - roi.tl()))) continue;
      parts.emplace_back(block_rect, &BlockAt(bx, by));
    }
  }
  const float* table = weight.data();
  static_assert(kMirror == 2, "AddReducedRow's cells are 2 x 2");
  const bool wide = CpuHasAvx512();
  cv::parallel_for_(cv::Range(0, static_cast<int>(parts.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const cv::Rect& block_rect = parts[static_cast<size_t>(i)].first;
      Block& b = *parts[static_cast<size_t>(i)].second;
      const cv::Rect overlap = block_rect & roi;
      const int bx = overlap.x - block_rect.x;
      for (int y = overlap.y; y < overlap.y + overlap.height; ++y) {
        const int by = y - block_rect.y;
        cv::Vec3f* acc = b.sum.ptr<cv::Vec3f>(by) + bx;
        float* wsum = b.weight.ptr<float>(by) + bx;
        const cv::Vec4b* px = warped.ptr<cv::Vec4b>(y - roi.y) + (overlap.x - roi.x);
        cv::Vec3f* small = b.small_sum.ptr<cv::Vec3f>(by / kMirror);
        float* small_w = b.small_weight.ptr<float>(by / kMirror);
        (wide ? AddReducedRowAvx512 : AddReducedRowScalar)(px, overlap.width, bx, table, acc, wsum, small, small_w);
      }
    }
  });
}

void PatchCanvas::Dense(const cv::Rect& rect, cv::Mat* sum, cv::Mat* weight, int factor) const {
  CV_Assert(factor >= 1 && kBlock % factor == 0 && rect.x % factor == 0 && rect.y % factor == 0 &&
            rect.width % factor == 0 && rect.height % factor == 0);
  const cv::Size small(rect.width / factor, rect.height / factor);
  *sum = cv::Mat::zeros(small, CV_32FC3);
  *weight = cv::Mat::zeros(small, CV_32F);
  const int bx0 = FloorDiv(rect.x, kBlock), by0 = FloorDiv(rect.y, kBlock);
  const int bx1 = FloorDiv(rect.x + rect.width - 1, kBlock), by1 = FloorDiv(rect.y + rect.height - 1, kBlock);
  for (int by = by0; by <= by1; ++by) {
    for (int bx = bx0; bx <= bx1; ++bx) {
      auto it = blocks_.find(Key(bx, by));
      if (it == blocks_.end()) continue;
      const cv::Rect block_rect(bx * kBlock, by * kBlock, kBlock, kBlock);
      const cv::Rect overlap = block_rect & rect;
      const cv::Rect src = overlap - block_rect.tl();
      const cv::Rect dst((overlap.x - rect.x) / factor, (overlap.y - rect.y) / factor,
                         overlap.width / factor, overlap.height / factor);
      if (factor == 1) {
        it->second.sum(src).copyTo((*sum)(dst));
        it->second.weight(src).copyTo((*weight)(dst));
      } else if (reduced_ && factor % kMirror == 0) {
        const cv::Rect small_src(src.x / kMirror, src.y / kMirror, src.width / kMirror, src.height / kMirror);
        if (factor == kMirror) {
          it->second.small_sum(small_src).copyTo((*sum)(dst));
          it->second.small_weight(small_src).copyTo((*weight)(dst));
        } else {
          cv::resize(it->second.small_sum(small_src), (*sum)(dst), dst.size(), 0, 0, cv::INTER_AREA);
          cv::resize(it->second.small_weight(small_src), (*weight)(dst), dst.size(), 0, 0, cv::INTER_AREA);
        }
      } else {
        cv::resize(it->second.sum(src), (*sum)(dst), dst.size(), 0, 0, cv::INTER_AREA);
        cv::resize(it->second.weight(src), (*weight)(dst), dst.size(), 0, 0, cv::INTER_AREA);
      }
    }
  }
}

namespace {

// Pixels [0, n) of a rendered row: where the weight passes kAlphaCut, the sums over the weight
// (times 1 / weight, rounded and saturated as cv::saturate_cast does) and alpha 255; elsewhere
// all zero.
void RenderRowScalar(const cv::Vec3f* s, const float* w, int n, cv::Vec4b* o) {
  for (int x = 0; x < n; ++x) {
    if (w[x] <= kAlphaCut) {
      o[x] = cv::Vec4b(0, 0, 0, 0);
      continue;
    }
    const float k = 1.0f / w[x];
    o[x] = cv::Vec4b(cv::saturate_cast<uchar>(s[x][0] * k), cv::saturate_cast<uchar>(s[x][1] * k),
                     cv::saturate_cast<uchar>(s[x][2] * k), 255);
  }
}

// Sixteen pixels at a time (AVX-512 VBMI): the same products, rounded to nearest even as
// cvRound, clamped to 0..255, and the bytes laid out BGRA by one permute.
__attribute__((target("avx512f,avx512bw,avx512vbmi,bmi2"))) void RenderRowAvx512(const cv::Vec3f* s, const float* w, int n,
                                                                            cv::Vec4b* o) {
  // Interleaved value i of the 48 belongs to pixel i / 3.
  alignas(64) int32_t owner[3][16];
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 16; ++i) owner[j][i] = (16 * j + i) / 3;
  // Output byte 4p + c is value 3p + c (c < 3) of the 48, or alpha (from a vector of 255s).
  alignas(64) uint8_t layout[64];
  for (int p = 0; p < 16; ++p)
    for (int c = 0; c < 4; ++c) layout[4 * p + c] = static_cast<uint8_t>(c < 3 ? 3 * p + c : 64);
  const __m512i lay = _mm512_load_si512(layout), opaque = _mm512_set1_epi8(char(0xFF));
  const __m512 cut = _mm512_set1_ps(kAlphaCut), one = _mm512_set1_ps(1.0f);
  const __m512i zero = _mm512_setzero_si512();
  int x = 0;
  for (; x + 16 <= n; x += 16) {
    const __m512 weight = _mm512_loadu_ps(w + x);
    const __mmask16 data = _mm512_cmp_ps_mask(weight, cut, _CMP_GT_OQ);
    const __m512 k = _mm512_div_ps(one, weight);
    const float* sums = s[x].val;
    __m128i bytes[3];
    for (int j = 0; j < 3; ++j) {
      const __m512 kj = _mm512_permutexvar_ps(_mm512_load_si512(owner[j]), k);
      const __m512i v = _mm512_max_epi32(_mm512_cvtps_epi32(_mm512_mul_ps(_mm512_loadu_ps(sums + 16 * j), kj)), zero);
      bytes[j] = _mm512_cvtusepi32_epi8(v);
    }
    // The 48 values' bytes in the low 48 bytes of one vector.
    const __m512i values = _mm512_inserti32x4(
        _mm512_inserti32x4(_mm512_castsi128_si512(bytes[0]), bytes[1], 1), bytes[2], 2);
    const __m512i bgra = _mm512_permutex2var_epi8(values, lay, opaque);
    // Pixels without data: all four bytes zero.
    const __mmask64 keep = _pdep_u64(data, 0x1111111111111111ull) * 0xF;  // each pixel's bit for its 4 bytes
    _mm512_storeu_si512(o + x, _mm512_maskz_mov_epi8(keep, bgra));
  }
  RenderRowScalar(s + x, w + x, n - x, o + x);
}

}  // namespace

namespace {

void RenderRows(const cv::Mat& sum, const cv::Mat& weight, cv::Mat& out, int y0, int y1) {
  const bool vbmi = CpuHasAvx512Vbmi();
  for (int y = y0; y < y1; ++y)
    (vbmi ? RenderRowAvx512 : RenderRowScalar)(sum.ptr<cv::Vec3f>(y), weight.ptr<float>(y), sum.cols,
                                               out.ptr<cv::Vec4b>(y));
}

}  // namespace

cv::Mat RenderSums(const cv::Mat& sum, const cv::Mat& weight) {
  CV_Assert(sum.type() == CV_32FC3 && weight.type() == CV_32F && sum.size() == weight.size());
  cv::Mat out(sum.size(), CV_8UC4);  // every pixel written below
  cv::parallel_for_(cv::Range(0, sum.rows),
                    [&](const cv::Range& range) { RenderRows(sum, weight, out, range.start, range.end); });
  return out;
}

cv::Mat PatchCanvas::Render(const cv::Rect& patch_rect) const {
  // Straight from the blocks (no dense copy of the sums in between); where no block is, zeros.
  cv::Mat out = cv::Mat::zeros(patch_rect.size(), CV_8UC4);
  if (patch_rect.empty()) return out;
  std::vector<std::pair<cv::Rect, const Block*>> parts;  // (rect in patch pixels, its block)
  for (int by = FloorDiv(patch_rect.y, kBlock); by <= FloorDiv(patch_rect.br().y - 1, kBlock); ++by)
    for (int bx = FloorDiv(patch_rect.x, kBlock); bx <= FloorDiv(patch_rect.br().x - 1, kBlock); ++bx) {
      const auto it = blocks_.find(Key(bx, by));
      if (it != blocks_.end())
        parts.emplace_back(cv::Rect(bx * kBlock, by * kBlock, kBlock, kBlock) & patch_rect, &it->second);
    }
  cv::parallel_for_(cv::Range(0, static_cast<int>(parts.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const cv::Rect& r = parts[size_t(i)].first;
      const Block& b = *parts[size_t(i)].second;
      const cv::Rect in_block(r.x - FloorDiv(r.x, kBlock) * kBlock, r.y - FloorDiv(r.y, kBlock) * kBlock, r.width,
                              r.height);
      cv::Mat view = out(r - patch_rect.tl());
      RenderRows(b.sum(in_block), b.weight(in_block), view, 0, r.height);
    }
  });
  return out;
}

bool PatchCanvas::Reduced(const cv::Rect& wanted, double scale, cv::Mat* sum, cv::Mat* weight, double* rest,
                          cv::Point2d* origin) const {
  const double step = scale_ / scale;  // canvas pixels per output pixel
  int factor = 1;
  while (factor * 2 <= step && factor * 2 <= kBlock / 4) factor *= 2;
  cv::Rect rect = Enclosing(cv::Rect2d(wanted.x * scale_, wanted.y * scale_, wanted.width * scale_,
                                       wanted.height * scale_)) & cdata_;
  if (rect.empty()) return false;
  // Aligned to the reduction factor, as Dense needs.
  const int x0 = FloorDiv(rect.x, factor) * factor, y0 = FloorDiv(rect.y, factor) * factor;
  const int x1 = -FloorDiv(-(rect.x + rect.width), factor) * factor;
  const int y1 = -FloorDiv(-(rect.y + rect.height), factor) * factor;
  rect = cv::Rect(x0, y0, x1 - x0, y1 - y0);
  Dense(rect, sum, weight, factor);
  *rest = factor / step;  // what remains after the power-of-two reduction
  // Output q = (u - rect.tl + 0.5) scale / scale_ - 0.5 with canvas pixel u = (p + 0.5) scale_ - 0.5.
  *origin = cv::Point2d(rect.x, rect.y) * (1.0 / scale_);
  return true;
}

bool PatchCanvas::RenderGray(const cv::Rect& wanted, double scale, cv::Mat* gray, cv::Mat* mask,
                             cv::Point2d* origin) const {
  cv::Mat sum, weight;
  double rest = 1;
  if (!Reduced(wanted, scale, &sum, &weight, &rest, origin)) return false;
  std::vector<cv::Mat> ch;
  cv::split(sum, ch);
  cv::Mat g = (0.114 * ch[0] + 0.587 * ch[1] + 0.299 * ch[2]);
  cv::divide(g, cv::max(weight, 1e-12), g);
  cv::Mat valid = weight > kAlphaCut * 4;
  if (std::abs(rest - 1.0) > 1e-6) {
    cv::resize(g, g, cv::Size(), rest, rest, cv::INTER_AREA);
    cv::resize(valid, valid, g.size(), 0, 0, cv::INTER_NEAREST);
  }
  g.convertTo(*gray, CV_8U);
  *mask = valid;
  return true;
}

bool PatchCanvas::RenderColour(double scale, cv::Mat* bgra, cv::Point2d* origin) const {
  cv::Mat sum, weight;
  double rest = 1;
  // Everything the canvas holds (Reduced clips to it).
  const cv::Rect wanted(data_.x - 2, data_.y - 2, data_.width + 4, data_.height + 4);
  if (cdata_.empty() || !Reduced(wanted, std::min(scale, scale_), &sum, &weight, &rest, origin)) return false;
  if (std::abs(rest - 1.0) > 1e-6) {
    cv::resize(sum, sum, cv::Size(), rest, rest, cv::INTER_AREA);
    cv::resize(weight, weight, sum.size(), 0, 0, cv::INTER_AREA);
  }
  *bgra = cv::Mat::zeros(sum.size(), CV_8UC4);
  for (int y = 0; y < sum.rows; ++y) {
    const cv::Vec3f* s = sum.ptr<cv::Vec3f>(y);
    const float* w = weight.ptr<float>(y);
    cv::Vec4b* o = bgra->ptr<cv::Vec4b>(y);
    for (int x = 0; x < sum.cols; ++x) {
      if (w[x] <= kAlphaCut * 4) continue;
      const float k = 1.0f / w[x];
      o[x] = cv::Vec4b(cv::saturate_cast<uchar>(s[x][0] * k), cv::saturate_cast<uchar>(s[x][1] * k),
                       cv::saturate_cast<uchar>(s[x][2] * k), 255);
    }
  }
  return true;
}

void PatchCanvas::ViewFromFrame(const cv::Matx33d& frame_to_patch, cv::Size frame, double scale, cv::Mat* gray,
                                cv::Mat* mask) const {
  const cv::Matx33d H = ToCanvas() * frame_to_patch;
  const cv::Size out(std::max(8, static_cast<int>(frame.width * scale)),
                     std::max(8, static_cast<int>(frame.height * scale)));
  // Only the canvas under the frame is made dense, then seen through the frame:
  // out pixel -> frame pixel -> patch -> dense pixel.
  // The canvas is averaged down by a power of two no larger than 1/scale (sums and weights
  // alike, so their ratio stays the blended colour), which keeps this cheap at ECC's scale.
  int factor = 1;
  while (factor * 2 <= scale_ / scale && factor * 2 <= kBlock / 4) factor *= 2;
  cv::Rect region = Enclosing(FrameBounds(H, frame)) & cdata_;
  if (region.empty()) {
    *gray = cv::Mat::zeros(out, CV_8U);
    *mask = cv::Mat::zeros(out, CV_8U);
    return;
  }
  const int x0 = FloorDiv(region.x, factor) * factor, y0 = FloorDiv(region.y, factor) * factor;
  const int x1 = -FloorDiv(-(region.x + region.width), factor) * factor;
  const int y1 = -FloorDiv(-(region.y + region.height), factor) * factor;
  region = cv::Rect(x0, y0, x1 - x0, y1 - y0);
  cv::Mat sum, weight;
  Dense(region, &sum, &weight, factor);
  const double s = 1.0 / scale;
  const cv::Matx33d S(s, 0, 0.5 * (s - 1), 0, s, 0.5 * (s - 1), 0, 0, 1);
  // patch -> dense pixel: q = (p - region.tl + 0.5) / factor - 0.5
  const double f = factor;
  const cv::Matx33d T(1 / f, 0, (-region.x + 0.5) / f - 0.5, 0, 1 / f, (-region.y + 0.5) / f - 0.5, 0, 0, 1);
  const cv::Matx33d view = T * H * S;
  cv::Mat sum_view, w_view;
  WarpPerspectiveLinear(sum, sum_view, view, out, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  WarpPerspectiveLinear(weight, w_view, view, out, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  std::vector<cv::Mat> ch;
  cv::split(sum_view, ch);
  cv::Mat safe = cv::max(w_view, 1e-12);
  cv::Mat g = (0.114 * ch[0] + 0.587 * ch[1] + 0.299 * ch[2]);
  cv::divide(g, safe, g);
  g.convertTo(*gray, CV_8U);
  *mask = w_view > kAlphaCut * 4;
}

}  // namespace rolamos
