// Renders any region of the global mosaic from the patches that cover it: each patch is read at
// the pyramid level its scale needs (through the bounded tile cache), warped into the region and
// blended with weights that fade to zero over `feather_px` at its no-data border, as the engine
// feathers frames, or by multi-band blending across seams. Thread-safe: compose renders blocks on all cores.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/tile_cache.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

// Where the part of a patch around one of its frames goes (after `rolamos align`, every frame has
// its own placement): patch level-0 pixel -> mosaic pixel, and the frame's centre on the mosaic.
struct LocalPlacement {
  cv::Matx33d to_mosaic;
  cv::Point2d centre;
};

struct PlacedPatch {
  int id = 0;
  std::string path;
  std::shared_ptr<const TiledImage> image;  // opened (and checked) when the patch was placed
  cv::Size size;           // level-0 pixels
  cv::Matx33d to_mosaic;   // patch level-0 pixel -> mosaic pixel (the best single one)
  cv::Rect2d bounds;       // in mosaic pixels
  // Per frame, when the frames were placed one by one: the patch is warped piecewise, each
  // mosaic pixel taken from where the frames nearest it put it (weights falling off with the
  // distance from each frame's centre, so the pieces join without a step).
  std::vector<LocalPlacement> local;
  double local_sigma = 1;  // mosaic pixels
  double gain = 1.0;       // exposure: the patch's brightness matched to its neighbours'

};

class PatchBlender {
 public:
  // `bands` > 0: multi-band blending (Burt & Adelson's Laplacian pyramids, `bands` levels) where
  // patches meet, with the seam where their feather weights cross (far from either's border);
  // 0: feathering only.
  PatchBlender(std::vector<PlacedPatch> patches, double scale, int feather_px, int bands = 0);
  // 8-bit BGRA of `rect` (mosaic pixels; alpha 255 where a patch has data), or an empty Mat when
  // no patch reaches it.
  cv::Mat Render(const cv::Rect& rect) const;
  const std::vector<PlacedPatch>& patches() const { return patches_; }

 private:
  // Whether patch k is the only one whose bounds reach `area`.
  bool OnlyOne(size_t k, const cv::Rect2d& area) const;
  struct Source;
  // Patch k's pixels for mosaic region `rect` and how they map onto it; false when it does not
  // reach the region.
  bool Read(size_t k, const cv::Rect& rect, Source* src) const;
  // Its weighted colour and weight (CV_32FC4: w*B, w*G, w*R, w) warped over the source's roi.
  void Warp(size_t k, const Source& src, cv::Mat* warped) const;
  cv::Mat RenderFeather(const cv::Rect& rect) const;
  // Multi-band over `rect` grown by a margin the pyramid's reach needs, so that neighbouring
  // blocks agree where they meet; the margin is cut off.
  cv::Mat RenderMultiband(const cv::Rect& rect) const;

  std::vector<PlacedPatch> patches_;
  double scale_;
  int feather_px_;
  int bands_;
};

}  // namespace rolamos
