// The patch being built in RAM: weighted colour sums and weight sums in patch coordinates (the
// first frame's pixel grid), kept in 256 x 256 blocks allocated where frames land, so the canvas
// grows in any direction without ever being copied and holds memory only where there is data.
// Its pixel budget is the paper's memory management: Fits() says whether one more frame keeps
// the patch's bounding box within it. The engine's working canvas (what frames are refined and
// recovered against) is kept at a reduced `scale`; the patch image itself is blended at full
// resolution when the patch closes. Every method speaks patch coordinates whatever the scale.
#pragma once

#include <array>
#include <cstdint>
#include <unordered_map>

#include <opencv2/core.hpp>

#include "engine/feather.h"

namespace rolamos {

class PatchCanvas {
 public:
  // `reduced`: keep the 2 x 2 averaged sums (for ECC's view); a canvas only rendered needs none.
  explicit PatchCanvas(long long pixel_budget, double scale = 1.0, bool reduced = true);

  // Bounding box (patch coordinates) of a frame warped by frame_to_patch.
  static cv::Rect2d FrameBounds(const cv::Matx33d& frame_to_patch, cv::Size frame);
  // The pixels of a frame placed by `frame_to_patch` that land in `rect` (patch coordinates),
  // with a margin for interpolation: what Add needs of the frame with `rect` as its clip. The
  // whole frame when part of `rect` lies beyond the frame's horizon; empty when none lands.
  static cv::Rect SourceRect(const cv::Matx33d& frame_to_patch, const cv::Rect& rect, cv::Size frame);
  // Whether the patch's bounding box, grown to hold `bounds`, stays within the budget.
  bool Fits(const cv::Rect2d& bounds) const;
  bool empty() const { return blocks_.empty(); }
  // Grey levels of a 16-bit frame are this many of its units: colour-corrected frames keep
  // fractions and values past 255 until the patch is rendered.
  static constexpr float kDeepScale = 64.0f;
  // Warps and accumulates a frame (BGR 8-bit, or 16-bit in kDeepScale units on a full-resolution
  // canvas without reduced sums) with its feather weights. With a `clip` (patch coordinates, a
  // full-resolution canvas), only what lands inside it is warped and kept: `frame` may then be
  // the part of a frame whose pixels land there (and `weights` that part's code).
  void Add(const cv::Mat& frame, const FeatherCode& weights, const cv::Matx33d& frame_to_patch,
           const cv::Rect& clip = cv::Rect());
  // A frame's colour with its feather code as a fourth channel (16-bit codes for a 16-bit frame):
  // what Add warps. A frame blended into several bands of a patch is interleaved once.
  static cv::Mat Interleave(const cv::Mat& frame, const cv::Mat& code);
  // The same for an 8-bit frame corrected to 16 bits on the way (times `colour`, CV_32FC3 of its
  // size, if given, and `scale`), in one pass: no clipping before the patch is rendered.
  static cv::Mat InterleaveDeep(const cv::Mat& frame, const cv::Mat& colour, double scale, const cv::Mat& code);
  // Add for a frame (or part of one) already interleaved, on a full-resolution canvas; `weight`
  // maps its code to weights.
  void AddInterleaved(const cv::Mat& bgrw, const std::array<float, 256>& weight, const cv::Matx33d& frame_to_patch,
                      const cv::Rect& clip = cv::Rect());
  // The blended mosaic (BGRA 8-bit, alpha 0 where nothing was added) of a rectangle of the
  // canvas's pixels (patch coordinates at scale 1).
  cv::Mat Render(const cv::Rect& patch_rect) const;
  // The mosaic seen from a frame: gray pixels and a validity mask in that frame's coordinates,
  // at `scale` of its resolution (for ECC refinement).
  void ViewFromFrame(const cv::Matx33d& frame_to_patch, cv::Size frame, double scale,
                     cv::Mat* gray, cv::Mat* mask) const;
  // The blended mosaic over `rect` (patch coordinates) in gray at `scale` of full resolution, and
  // where it holds data: what a frame that lost the thread is registered against. `rect` is
  // clipped to the data. Returns false when nothing is there; else `origin` is the patch
  // coordinates that image pixel (0, 0) stands for at `scale` (q = (p - origin + 0.5) scale - 0.5).
  bool RenderGray(const cv::Rect& rect, double scale, cv::Mat* gray, cv::Mat* mask, cv::Point2d* origin) const;
  // The whole blended canvas in colour (BGRA 8-bit, alpha 0 where nothing was added) at `scale`
  // of full resolution (at most the canvas's): the open patch as a live preview. `origin` as for
  // RenderGray. False when the canvas is empty.
  bool RenderColour(double scale, cv::Mat* bgra, cv::Point2d* origin) const;
  double scale() const { return scale_; }
  const cv::Rect& data() const { return data_; }
  long long pixel_budget() const { return budget_; }

 private:
  // Add for an interleaved frame already at the canvas's scale; `frame` is its full size.
  void AddAtScale(const cv::Mat& bgrw, const std::array<float, 256>& weight, const cv::Matx33d& frame_to_patch,
                  cv::Size frame, const cv::Rect& clip);
  static constexpr int kBlock = 256;
  // The working canvas's blocks also keep their sums averaged over 2 x 2 cells, accumulated as
  // frames are added: ECC looks at the mosaic at a quarter of full resolution (half the working
  // canvas's) for every frame, and reducing the sums each time cost more than the registration.
  static constexpr int kMirror = 2;
  struct Block {
    cv::Mat sum;           // CV_32FC3: sum of weight * colour
    cv::Mat weight;        // CV_32F: sum of weights
    cv::Mat small_sum;     // CV_32FC3, kBlock / kMirror square: 4 x 4 means of `sum`
    cv::Mat small_weight;  // CV_32F: 4 x 4 means of `weight`
  };
  static int64_t Key(int bx, int by) { return (int64_t(bx) << 32) ^ uint32_t(by); }
  // The block at (bx, by), created (zero) if there is none yet.
  Block& BlockAt(int bx, int by);
  // AddAtScale's two ways of accumulating a frame placed by H (frame -> canvas pixels) over
  // `roi` (canvas pixels): at full resolution blended straight from the frame; on the reduced
  // working canvas from its warped copy (`warped`, roi's size), keeping the 2 x 2 means too.
  void AddBlended(const cv::Mat& bgrw, const std::array<float, 256>& weight, const cv::Matx33d& H, const cv::Rect& roi);
  void AddReduced(const cv::Mat& warped, const std::array<float, 256>& weight, const cv::Rect& roi);
  // Dense copies of the sums over `rect` (zeros where no block exists), reduced by `factor`
  // (1, 2, 4, ... up to the block size) with area averaging; `rect` must be aligned to it.
  void Dense(const cv::Rect& rect, cv::Mat* sum, cv::Mat* weight, int factor = 1) const;

  // The sums over `wanted` (patch coordinates, clipped to the data) reduced by the largest power
  // of two towards `scale`; `rest` is the resize still needed to reach it, `origin` as RenderGray's.
  bool Reduced(const cv::Rect& wanted, double scale, cv::Mat* sum, cv::Mat* weight, double* rest,
               cv::Point2d* origin) const;
  // Patch coordinates -> canvas pixels: u = (p + 0.5) scale - 0.5.
  cv::Matx33d ToCanvas() const;

  long long budget_;
  double scale_ = 1.0;
  bool reduced_ = true;
  cv::Rect data_;    // patch coordinates: the budget's bounding box
  cv::Rect cdata_;   // canvas pixels holding data
  std::unordered_map<int64_t, Block> blocks_;
};

// Blended colour from a canvas's sums (CV_32FC3) and weights (CV_32F): sum / weight rounded and
// saturated to 8 bits, alpha 255, where the weight passes kAlphaCut; elsewhere all zero (no
// data, not black data: the alpha says so). BGRA, CV_8UC4.
cv::Mat RenderSums(const cv::Mat& sum, const cv::Mat& weight);

}  // namespace rolamos
