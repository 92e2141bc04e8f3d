// Streaming writer of pyramidal tiled BigTIFF files (store format v1, docs/store-format.md).
//
// Level 0 arrives as horizontal bands of `band_height()` rows, top to bottom; the image is never
// whole in memory. Reduced levels are built on the fly by alpha-aware 2x2 area averaging and kept
// as compressed tiles in a temporary file until Finish() appends them as reduced-resolution IFDs.
// Tiles are compressed by libtiff's own codecs on all cores. The file appears under its final
// name only when Finish() succeeds; a writer destroyed before that removes its temporary files.
#pragma once

#include <functional>  // PyramidTiffWriter::BeforeRename
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/image_format.hpp"

namespace rolamos {

struct TiffWriteOptions {
  Compression compression = Compression::kJpeg;
  int quality = 90;       // JPEG and WebP quality, 1..100
  int tile_size = 256;    // 256 or 512
  bool pyramid = true;    // reduced levels down to one tile
  int threads = 0;        // compression threads; 0 = one per core
  int zstd_level = 9;     // 1..22
  int deflate_level = 6;  // 1..9
  // libwebp's effort, 0..6 (cwebp -m): 4 is libtiff's own choice; `mosaic --compression webp`
  // writes its intermediate patches at 0, 3.3x faster for ~0.5 dB at the same quality and size.
  int webp_method = 4;

  bool IsValid(const PixelLayout& layout, std::string* error) const;
};

struct TiffWriteStats {
  long long tiles = 0;
  int levels = 0;
  long long bytes = 0;
  double encode_cpu_seconds = 0;  // the compression threads' CPU time, all tiles and levels
};

class PyramidTiffWriter {
 public:
  // Throws Error when the options do not fit the layout or the file cannot be created.
  PyramidTiffWriter(const std::string& path, const PixelLayout& layout,
                    const TiffWriteOptions& options);
  ~PyramidTiffWriter();
  PyramidTiffWriter(const PyramidTiffWriter&) = delete;
  PyramidTiffWriter& operator=(const PyramidTiffWriter&) = delete;

  int band_height() const;
  // The next band of level 0: band_height() rows (fewer for the last), full width, layout's type.
  void WriteBand(const cv::Mat& band);
  // GeoTIFF tags, written through GDAL when the file is complete (tiff_writer_georef.cc).
  void SetGeoref(const Georef& georef);
  // Writes the reduced levels and the georeference and moves the file to its name.
  TiffWriteStats Finish();

 private:
  const std::string& path() const;
  // Runs on the complete file (by its temporary name) before it is moved to its name.
  void BeforeRename(std::function<void(const std::string& tmp_path)> step);

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Writes an image that is already in memory (small images, tests).
// Two overloads rather than a default argument: the one without a georeference does not bring
// GDAL into a program (tools/main.cc).
TiffWriteStats WritePyramidTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options);
TiffWriteStats WritePyramidTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options,
                                const Georef* georef);

}  // namespace rolamos
