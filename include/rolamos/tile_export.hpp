// `rolamos tiles`: the same tiles the server cuts, written once to a directory that any static
// web server can host: Deep Zoom (NAME.dzi + NAME_files/LEVEL/X_Y.jpg, for OpenSeadragon) or XYZ
// (NAME/Z/X/Y.jpg, for Leaflet/QGIS), with images.json describing them.
#pragma once

#include <array>

#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct TileExportOptions {
  std::string format = "dzi";  // dzi | xyz
  std::string ext = "jpg";     // jpg | png | webp
  int jpeg_quality = 85;
  double cache_mb = 256;
  // xyz: JPEG's colour for "no data" (BGR); PNG and WebP leave it transparent.
  std::array<int, 3> background{0, 0, 0};
  // xyz: where the directory will be served from (http://host/path), for the documents that
  // name their tiles by URL (TileJSON, WMTS capabilities, GDAL WMS); "" = file:// URLs of the
  // directory as written.
  std::string base_url;
  bool IsValid(std::string* error) const;
};

struct TileExportResult {
  int images = 0;
  long long tiles = 0;
  long long webmercator_tiles = 0;  // xyz of a georeferenced image: its Web Mercator tiles too
};

// Writes into `dir` (a new directory; the tiles appear under that name only when complete).
TileExportResult ExportTiles(Store store, const std::string& dir, const TileExportOptions& options,
                             const ProgressFn& progress = nullptr);

}  // namespace rolamos
