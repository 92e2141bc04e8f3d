// `rolamos tiles`: the same tiles the server cuts, written once to a directory that any static
// web server can host: Deep Zoom (NAME.dzi + NAME_files/LEVEL/X_Y.jpg, for OpenSeadragon) or XYZ
// (NAME/Z/X/Y.jpg, for Leaflet/QGIS), with images.json describing them.
#pragma once

#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct TileExportOptions {
  std::string format = "dzi";  // dzi | xyz
  std::string ext = "jpg";     // jpg | png
  int jpeg_quality = 85;
  double cache_mb = 256;
  bool IsValid(std::string* error) const;
};

struct TileExportResult {
  int images = 0;
  long long tiles = 0;
};

// Writes into `dir` (a new directory; the tiles appear under that name only when complete).
TileExportResult ExportTiles(Store store, const std::string& dir, const TileExportOptions& options,
                             const ProgressFn& progress = nullptr);

}  // namespace rolamos
