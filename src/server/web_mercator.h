// Georeferenced web tiles: a map with a CRS cut into the tiles of Web Mercator (EPSG:3857, the
// "GoogleMapsCompatible" grid every web map and GIS uses), each warped on demand through GDAL
// (gdalwarp's library call, overviews chosen by resolution). Also what TileJSON and WMTS say of it.
#pragma once

#include <array>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

namespace rolamos {

class WebMercatorTiles {
 public:
  static constexpr int kTile = 256;
  static constexpr double kHalfWorld = 20037508.342789244;  // metres, Web Mercator's half extent

  // nullptr when the image has no CRS a web map can place (none, or a local engineering frame);
  // `why` says which. Throws Error when the file cannot be read.
  static std::unique_ptr<WebMercatorTiles> Open(const std::string& path, std::string* why);

  // Zoom levels worth serving: from the one where the map fits a tile or two to the first whose
  // pixels are as fine as the map's own.
  int min_zoom() const { return min_zoom_; }
  int max_zoom() const { return max_zoom_; }
  // The map's extent: Web Mercator metres (xmin, ymin, xmax, ymax), and WGS 84 degrees
  // (west, south, east, north).
  const std::array<double, 4>& bounds_3857() const { return bounds_; }
  const std::array<double, 4>& bounds_wgs84() const { return lonlat_; }
  const std::string& path() const { return path_; }

  // Whether tile (z, x, y) is in the grid (0 <= x, y < 2^z, z <= 30) and touches the map.
  bool InGrid(int z, long long x, long long y) const;
  bool Touches(int z, long long x, long long y) const;
  // Tile (z, x, y): 256 x 256 BGRA, alpha 0 where the map has no data. Empty when outside the
  // grid; fully transparent when in the grid but off the map. Throws Error when GDAL fails.
  cv::Mat Tile(int z, long long x, long long y) const;
  // Web Mercator extent of tile (z, x, y): (xmin, ymin, xmax, ymax).
  static std::array<double, 4> TileBounds(int z, long long x, long long y);

 private:
  std::string path_;
  std::array<double, 4> bounds_{}, lonlat_{};
  int min_zoom_ = 0, max_zoom_ = 0;
};

}  // namespace rolamos
