#include "raster/tiff_tags.h"

#include "rolamos/version.hpp"

namespace rolamos {

bool UsesYCbCr(const PixelLayout& layout, const TiffWriteOptions& options) {
  return (options.compression == Compression::kJpeg || options.compression == Compression::kJpegMask) &&
         layout.channels == 3;
}

void SetLevelTags(TIFF* tif, const PixelLayout& layout, const TiffWriteOptions& options,
                  const LevelTags& level, bool for_encoding) {
  TIFFSetField(tif, TIFFTAG_SUBFILETYPE, level.reduced ? FILETYPE_REDUCEDIMAGE : 0);
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, level.width);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, level.height);
  TIFFSetField(tif, TIFFTAG_TILEWIDTH, static_cast<uint32_t>(options.tile_size));
  TIFFSetField(tif, TIFFTAG_TILELENGTH, static_cast<uint32_t>(options.tile_size));
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, static_cast<uint16_t>(layout.channels));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, static_cast<uint16_t>(layout.bits));
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_ORIENTATION, ORIENTATION_TOPLEFT);
  if (layout.HasAlpha()) {
    uint16_t extra = EXTRASAMPLE_UNASSALPHA;
    TIFFSetField(tif, TIFFTAG_EXTRASAMPLES, 1, &extra);
  }
  // OpenImageIO reads the IFD chain as MIP levels only with this tag (DESIGN.md).
  if (level.mip_tag) TIFFSetField(tif, TIFFTAG_PIXAR_TEXTUREFORMAT, "Plain Texture");
  TIFFSetField(tif, TIFFTAG_SOFTWARE, "rolamos " ROLAMOS_VERSION_STRING);

  const bool colour = layout.channels >= 3;
  switch (options.compression) {
    case Compression::kNone:
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
      break;
    case Compression::kJpeg:
    case Compression::kJpegMask:
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_JPEG);
      // Tiles are abbreviated streams; the shared quantisation and standard Huffman tables go
      // in the JPEGTables tag (SetJpegTables). Standard tables also spare the second, optimising
      // pass over every tile.
      if (for_encoding) TIFFSetField(tif, TIFFTAG_JPEGQUALITY, options.quality);
      break;
    case Compression::kDeflate:
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
      TIFFSetField(tif, TIFFTAG_PREDICTOR, PREDICTOR_HORIZONTAL);
      if (for_encoding) TIFFSetField(tif, TIFFTAG_ZIPQUALITY, options.deflate_level);
      break;
    case Compression::kZstd:
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ZSTD);
      TIFFSetField(tif, TIFFTAG_PREDICTOR, PREDICTOR_HORIZONTAL);
      if (for_encoding) TIFFSetField(tif, TIFFTAG_ZSTD_LEVEL, options.zstd_level);
      break;
    case Compression::kWebp:
      TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_WEBP);
      if (for_encoding) TIFFSetField(tif, TIFFTAG_WEBP_LEVEL, options.quality);
      break;
  }
  if (UsesYCbCr(layout, options)) {
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_YCBCR);
    TIFFSetField(tif, TIFFTAG_YCBCRSUBSAMPLING, 2, 2);
    if (for_encoding) TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
  } else {
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, colour ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK);
  }
}

void SetMaskTags(TIFF* tif, const TiffWriteOptions& options, const LevelTags& level) {
  TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_MASK | (level.reduced ? FILETYPE_REDUCEDIMAGE : 0));
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, level.width);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, level.height);
  TIFFSetField(tif, TIFFTAG_TILEWIDTH, static_cast<uint32_t>(options.tile_size));
  TIFFSetField(tif, TIFFTAG_TILELENGTH, static_cast<uint32_t>(options.tile_size));
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, static_cast<uint16_t>(1));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, static_cast<uint16_t>(1));
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_ORIENTATION, ORIENTATION_TOPLEFT);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MASK);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
}

void SetJpegTables(TIFF* tif, const std::vector<uint8_t>& tables) {
  if (!tables.empty())
    TIFFSetField(tif, TIFFTAG_JPEGTABLES, static_cast<uint32_t>(tables.size()), tables.data());
}

}  // namespace rolamos
