// The tags of one level of a store-format TIFF, set the same way on the file being written and
// on the in-memory TIFFs whose codecs compress its tiles.
#pragma once

#include <tiffio.h>

#include <vector>

#include "rolamos/image_format.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct LevelTags {
  uint32_t width = 0;
  uint32_t height = 0;
  bool reduced = false;  // NewSubfileType = 1
  // PIXAR_TEXTUREFORMAT, for OpenImageIO to read the chain as MIP levels; off where masks follow
  // the levels (it would take them for more levels).
  bool mip_tag = true;
};

// Sets every tag of a level; `for_encoding` adds the pseudo-tags the codec needs when it is fed
// pixels (JPEG colour conversion, codec levels) rather than raw tiles.
void SetLevelTags(TIFF* tif, const PixelLayout& layout, const TiffWriteOptions& options,
                  const LevelTags& level, bool for_encoding);

// The tags of a level's transparency mask (Compression::kJpegMask): 1 bit a pixel, 1 where the
// image has data, deflate; NewSubfileType 4, or 5 for reduced levels, as GDAL writes its internal
// masks.
void SetMaskTags(TIFF* tif, const TiffWriteOptions& options, const LevelTags& level);
// The JPEGTables of a JPEG level (from TileEncoder::JpegTables), shared by all its tiles.
void SetJpegTables(TIFF* tif, const std::vector<uint8_t>& tables);

// Whether JPEG stores this layout as YCbCr (colour without alpha) rather than as plain samples.
bool UsesYCbCr(const PixelLayout& layout, const TiffWriteOptions& options);

}  // namespace rolamos
