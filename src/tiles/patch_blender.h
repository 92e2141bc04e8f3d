// Renders any region of the global mosaic from the patches that cover it: each patch is read at
// the pyramid level its scale needs (through the bounded tile cache), warped into the region and
// blended with weights that fade to zero over `feather_px` at its no-data border, as the engine
// feathers frames. Thread-safe: compose renders blocks on all cores.
#pragma once

#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/tile_cache.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

struct PlacedPatch {
  int id = 0;
  std::string path;
  cv::Size size;           // level-0 pixels
  cv::Matx33d to_mosaic;   // patch level-0 pixel -> mosaic pixel
  cv::Rect2d bounds;       // in mosaic pixels
};

class PatchBlender {
 public:
  PatchBlender(std::vector<PlacedPatch> patches, double scale, int feather_px,
               std::shared_ptr<TileCache> cache);
  // 8-bit BGRA of `rect` (mosaic pixels; alpha 255 where a patch has data), or an empty Mat when
  // no patch reaches it.
  cv::Mat Render(const cv::Rect& rect) const;
  const std::vector<PlacedPatch>& patches() const { return patches_; }

 private:
  const TiledImage& Image(size_t k) const;
  // Whether patch k is the only one whose bounds reach `area`.
  bool OnlyOne(size_t k, const cv::Rect2d& area) const;

  std::vector<PlacedPatch> patches_;
  double scale_;
  int feather_px_;
  std::shared_ptr<TileCache> cache_;
  mutable std::vector<std::unique_ptr<TiledImage>> images_;  // opened on first use
  std::unique_ptr<std::once_flag[]> opened_;
};

}  // namespace rolamos
