// Read access to a (pyramidal) tiled image at any level or scale through the bounded TileCache.
// Reads our BigTIFFs and any tiled TIFF / COG that GDAL writes; other images OpenImageIO reads
// are served in tiles of their scanlines.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/tile_cache.hpp"

namespace rolamos {

struct LevelInfo {
  long long width = 0;
  long long height = 0;
  int tile_width = 0;   // 0 when the level is stored in strips
  int tile_height = 0;
};

struct TiledImageInfo {
  std::string path;
  std::string format;        // "tiff", or the OpenImageIO format name
  int channels = 0;          // 1..4
  int bits = 8;              // 8 or 16
  bool has_alpha = false;
  bool bigtiff = false;
  std::string compression;   // as the file names it ("jpeg", "zstd", ...)
  std::vector<LevelInfo> levels;
  std::optional<Georef> georef;
};

class TiledImage {
 public:
  // Throws Error naming the file when it is missing, truncated, not an image or too large to be
  // plausible.
  static TiledImage Open(const std::string& path, std::shared_ptr<TileCache> cache = nullptr);

  const TiledImageInfo& info() const;
  long long width() const { return info().levels[0].width; }
  long long height() const { return info().levels[0].height; }
  int num_levels() const { return static_cast<int>(info().levels.size()); }
  int cv_type() const;

  // Pixels of `region` (in that level's coordinates) as BGR(A)/gray; throws Error when the region
  // leaves the level or a tile cannot be decoded.
  cv::Mat ReadRegion(int level, const cv::Rect& region) const;
  // The same into `dst` (region-sized, cv_type(); may be a view into a larger Mat): no copy.
  // `file_order`: the channels as the file stores them (RGB(A)), not swapped to OpenCV's BGR(A).
  void ReadRegionInto(int level, const cv::Rect& region, cv::Mat& dst, bool file_order = false) const;
  // `region0` in level-0 coordinates, resampled by `scale` (0 < scale <= 1): reads the nearest
  // finer level and area-averages the rest of the way.
  cv::Mat ReadScaled(const cv::Rect& region0, double scale) const;
  // Output pixel (i, j) covers level-0 [x0 + i/scale, x0 + (i+1)/scale) x [y0 + j/scale, ...):
  // bands read this way join without seams.
  cv::Mat ReadResampled(double x0, double y0, double scale, cv::Size out) const;
  // The coarsest level whose resolution is still at least `scale` of level 0.
  int LevelForScale(double scale) const;

  const std::shared_ptr<TileCache>& cache() const;

 private:
  struct Impl;
  // Images other than tiled TIFFs (strips, JPEG, PNG, ...): through OpenImageIO's cache.
  void ReadThroughOiio(int level, const cv::Rect& region, cv::Mat& out) const;
  std::shared_ptr<const Impl> impl_;
};

// The cache readers use when none is given (256 MB unless ROLAMOS_CACHE_MB says otherwise).
std::shared_ptr<TileCache> DefaultTileCache();

}  // namespace rolamos
