// Reads an image band by band (full-width rows) from whatever can read it: the tile cache
// (OpenImageIO: TIFF, PNG, JPEG, EXR, ...) first, GDAL for the formats only GDAL knows.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/image_format.hpp"
#include "rolamos/tile_cache.hpp"

namespace rolamos {

class BandSource {
 public:
  virtual ~BandSource() = default;
  const PixelLayout& layout() const { return layout_; }
  const std::optional<Georef>& georef() const { return georef_; }
  const std::string& reader() const { return reader_; }
  // Rows [y, y + rows) at full width, OpenCV channel order. Throws Error.
  virtual cv::Mat Read(long long y, int rows) = 0;

 protected:
  PixelLayout layout_;
  std::optional<Georef> georef_;
  std::string reader_;
};

std::unique_ptr<BandSource> OpenBandSource(const std::string& path,
                                           std::shared_ptr<TileCache> cache);

}  // namespace rolamos
