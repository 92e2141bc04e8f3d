#include "engine/patch_canvas.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "engine/bilinear_warp.h"
#include "engine/canvas_rows.h"
#include "engine/channel_shuffle.h"
#include "engine/perspective_warp.h"
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

cv::Mat PatchCanvas::InterleaveDeep(const cv::Mat& frame, const cv::Mat& colour, double scale, const cv::Mat& code) {
  CV_Assert(frame.type() == CV_8UC3 && code.type() == CV_8U && code.size() == frame.size());
  CV_Assert(colour.empty() || (colour.type() == CV_32FC3 && colour.size() == frame.size()));
  cv::Mat bgrw(frame.size(), CV_16UC4);
  const float s = static_cast<float>(scale);
  cv::parallel_for_(cv::Range(0, frame.rows), [&](const cv::Range& range) {
    std::vector<ushort> row(3 * static_cast<size_t>(frame.cols));
    for (int y = range.start; y < range.end; ++y) {
      const float* c = colour.empty() ? nullptr : colour.ptr<float>(y);
      CorrectRow(frame.ptr<uchar>(y), c, s, 3 * frame.cols, row.data());
      InterleaveDeepRow(row.data(), code.ptr<uchar>(y), frame.cols, bgrw.ptr<cv::Vec4w>(y));
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
  // A whole frame's feather code is 0 on all four edges; a band's part of a frame, where it
  // meets the frame's edges.
  const CodeEdges zero = ZeroCodeEdges(bgrw);
  cv::parallel_for_(cv::Range(0, static_cast<int>(parts.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const cv::Rect& overlap = parts[static_cast<size_t>(i)].first;
      Block& b = *parts[static_cast<size_t>(i)].second;
      const cv::Rect in_block(overlap.x - FloorDiv(overlap.x, kBlock) * kBlock,
                              overlap.y - FloorDiv(overlap.y, kBlock) * kBlock, overlap.width, overlap.height);
      cv::Mat sum = b.sum(in_block), weight_sum = b.weight(in_block);
      WarpAccumulate(bgrw, cv::Matx33d(1, 0, -overlap.x, 0, 1, -overlap.y, 0, 0, 1) * H, weight, unit, sum, weight_sum,
                     zero);
    }
  });
}

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
        AddReducedRow(px, overlap.width, bx, table, acc, wsum, small, small_w);
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

void RenderRows(const cv::Mat& sum, const cv::Mat& weight, cv::Mat& out, int y0, int y1) {
  for (int y = y0; y < y1; ++y)
    RenderSumsRow(sum.ptr<cv::Vec3f>(y), weight.ptr<float>(y), sum.cols, out.ptr<cv::Vec4b>(y));
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
