// Any image OpenImageIO or GDAL reads -> pyramidal tiled BigTIFF, read band by band.
#pragma once

#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct ConvertOptions {
  std::string input;
  std::string output;
  TiffWriteOptions tiff;
  double cache_mb = 16.0;  // reading goes band by band: each tile is decoded once

  bool IsValid(std::string* error) const;
};

struct ConvertResult {
  long long width = 0;
  long long height = 0;
  int channels = 0;
  TiffWriteStats stats;
  std::string reader;  // "oiio" or "gdal"
};

ConvertResult ConvertImage(const ConvertOptions& options, const ProgressFn& progress = nullptr);

}  // namespace rolamos
