// Cloud Optimized GeoTIFF export through GDAL's COG driver.
#pragma once

#include <string>

#include "rolamos/image_format.hpp"
#include "rolamos/progress.hpp"

namespace rolamos {

struct CogOptions {
  Compression compression = Compression::kJpeg;
  int quality = 90;
  int tile_size = 512;
  bool IsValid(std::string* error) const;
};

// Writes `output` as a COG from any raster GDAL reads (our BigTIFFs included), keeping their
// georeference; the file appears only when complete.
void ExportCog(const std::string& source, const std::string& output, const CogOptions& options,
               const ProgressFn& progress = nullptr);

}  // namespace rolamos
