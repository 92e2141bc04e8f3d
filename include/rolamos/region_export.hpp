// A region of a tiled image at any level or scale: streamed to a pyramidal tiled TIFF when large,
// PNG or JPEG when it fits in memory.
#pragma once

#include <string>

#include <opencv2/core.hpp>

#include "rolamos/progress.hpp"
#include "rolamos/tiff_writer.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

struct ExportOptions {
  cv::Rect2d region;     // level-0 pixels; empty = the whole image
  int level = -1;        // read this level as it is (region still in level-0 pixels)
  double scale = 1.0;    // or resample to this scale (used when level < 0)
  std::string output;    // .tif/.tiff (streamed, pyramidal), .png, .jpg/.jpeg
  TiffWriteOptions tiff; // for .tif output
  int jpeg_quality = 92; // for .jpg output
  // PNG/JPEG outputs are built in memory: refuse larger ones and point to .tif instead.
  long long max_memory_pixels = 256LL << 20;

  bool IsValid(std::string* error) const;
};

struct ExportResult {
  long long width = 0;
  long long height = 0;
  int level = 0;
  double scale = 1.0;
};

ExportResult ExportRegion(const TiledImage& source, const ExportOptions& options,
                          const ProgressFn& progress = nullptr);

}  // namespace rolamos
