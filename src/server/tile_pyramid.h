// The tile grid served and exported for one image: Deep Zoom levels (level L is the image scaled
// by 2^(L - max), max = ceil(log2(longest side)), down to one pixel) cut into 256-pixel tiles on
// demand from the stored pyramid, and the XYZ zoom numbering over the same levels (zoom 0 = the
// finest level that fits one tile).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/store.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

// The checks the tile server and the static tile export share: JPEG quality and the cache bound.
bool TileEncodingIsValid(int jpeg_quality, double cache_mb, std::string* error);

class TilePyramid {
 public:
  static constexpr int kTile = 256;
  explicit TilePyramid(std::shared_ptr<TiledImage> image);

  const TiledImage& image() const { return *image_; }
  const std::shared_ptr<TiledImage>& image_ptr() const { return image_; }
  int max_level() const { return max_level_; }
  // DZI level of XYZ zoom 0; XYZ zoom z is DZI level z + xyz_shift().
  int xyz_shift() const { return xyz_shift_; }
  int xyz_max_zoom() const { return max_level_ - xyz_shift_; }
  cv::Size LevelSize(int level) const;
  // Tile (tx, ty) of a DZI level, BGR(A); empty when outside the level. Edge tiles are cut to
  // the image (Deep Zoom's convention).
  cv::Mat Tile(int level, long long tx, long long ty) const;
  // XYZ tile (z, x, y): always 256 x 256 BGRA, alpha 0 where the image has no data or does not
  // reach (every XYZ client expects whole tiles); empty when (x, y) is outside zoom z's 2^z grid
  // or z is past full resolution.
  cv::Mat XyzTile(int z, long long x, long long y) const;
  // Whether XYZ tile (z, x, y) holds any of the image (the tiles `rolamos tiles` writes).
  bool XyzTileTouchesImage(int z, long long x, long long y) const;
  // "jpg", "png" or "webp" (at `jpeg_quality`, alpha kept); JPEG has no alpha: pixels without
  // data take `background` (BGR), alpha-blended at the edges of the data.
  static std::vector<uchar> Encode(cv::Mat tile, const std::string& ext, int jpeg_quality,
                                   const cv::Scalar& background = cv::Scalar(0, 0, 0));
  // The Deep Zoom descriptor (NAME.dzi) of this image.
  std::string DziDescriptor(const std::string& ext) const;

 private:
  std::shared_ptr<TiledImage> image_;
  int max_level_ = 0;
  int xyz_shift_ = 0;
};

// What a store offers as tiled images, by the names the server and the export use:
// ("mosaic", its file) when composed, then ("patch-N", file) for every patch.
std::vector<std::pair<std::string, std::string>> StoreImages(const Store& store);

}  // namespace rolamos
