#include "raster/tiff_inspect.h"

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "rolamos/error.hpp"
#include "raster/tiff_file.h"

namespace rolamos {
namespace {

constexpr int kMaxDirectories = 256;
constexpr uint32_t kMaxTileSide = 8192;
constexpr uint32_t kMaxSide = 0x7fffffffu;

}  // namespace

bool HasTiffSignature(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[4] = {0, 0, 0, 0};
  if (!in.read(reinterpret_cast<char*>(b), 4)) return false;
  const bool ii = b[0] == 'I' && b[1] == 'I' && (b[2] == 42 || b[2] == 43) && b[3] == 0;
  const bool mm = b[0] == 'M' && b[1] == 'M' && b[2] == 0 && (b[3] == 42 || b[3] == 43);
  return ii || mm;
}

std::string TiffCompressionName(uint16_t c) {
  switch (c) {
    case COMPRESSION_NONE: return "none";
    case COMPRESSION_LZW: return "lzw";
    case COMPRESSION_OJPEG: return "old-jpeg";
    case COMPRESSION_JPEG: return "jpeg";
    case COMPRESSION_ADOBE_DEFLATE:
    case COMPRESSION_DEFLATE: return "deflate";
    case COMPRESSION_PACKBITS: return "packbits";
    case COMPRESSION_LZMA: return "lzma";
    case COMPRESSION_ZSTD: return "zstd";
    case COMPRESSION_WEBP: return "webp";
    case COMPRESSION_LERC: return "lerc";
    default: return "code " + std::to_string(c);
  }
}

TiffStructure InspectTiff(const std::string& path) {
  TiffStructure s;
  std::error_code ec;
  s.file_size = std::filesystem::file_size(path, ec);
  if (ec) Fail(path, "cannot read: " + ec.message());
  std::unique_ptr<TiffFile> file;
  try {
    file = TiffFile::Open(path, "rm");
  } catch (const Error& e) {
    Fail(path, "is not a readable TIFF (" + std::to_string(s.file_size) +
                   " bytes: truncated or damaged?): " + std::string(e.what()).substr(path.size() + 2));
  }
  TIFF* tif = file->get();
  s.bigtiff = TIFFIsBigTIFF(tif) != 0;
  int index = 0;
  do {
    if (index >= kMaxDirectories)
      Fail(path, "more than " + std::to_string(kMaxDirectories) + " image directories");
    TiffDirectory d;
    d.index = index;
    const std::string where = path + " (IFD " + std::to_string(index) + ")";
    TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &d.width);
    TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &d.height);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &d.samples);
    TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &d.bits);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &d.sample_format);
    TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &d.compression);
    TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &d.planar);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SUBFILETYPE, &d.subfile_type);
    TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &d.photometric);
    uint16_t n_extra = 0;
    uint16_t* extra = nullptr;
    if (TIFFGetField(tif, TIFFTAG_EXTRASAMPLES, &n_extra, &extra) && n_extra > 0)
      d.has_alpha = extra[0] == EXTRASAMPLE_ASSOCALPHA || extra[0] == EXTRASAMPLE_UNASSALPHA;
    d.is_mask = (d.subfile_type & FILETYPE_MASK) != 0 || d.photometric == PHOTOMETRIC_MASK;
    d.tiled = TIFFIsTiled(tif) != 0;
    if (d.width == 0 || d.height == 0 || d.width > kMaxSide || d.height > kMaxSide)
      Fail(where, "image size " + std::to_string(d.width) + "x" + std::to_string(d.height) +
                      " is empty or impossible");
    if (d.tiled) {
      TIFFGetField(tif, TIFFTAG_TILEWIDTH, &d.tile_width);
      TIFFGetField(tif, TIFFTAG_TILELENGTH, &d.tile_height);
      if (d.tile_width == 0 || d.tile_height == 0 || d.tile_width > kMaxTileSide ||
          d.tile_height > kMaxTileSide || d.tile_width % 16 || d.tile_height % 16)
        Fail(where, "tile size " + std::to_string(d.tile_width) + "x" +
                        std::to_string(d.tile_height) +
                        " is invalid (multiples of 16 up to 8192 are allowed)");
    }
    if (d.samples == 0 || d.samples > 64)
      Fail(where, std::to_string(d.samples) + " samples per pixel is impossible");
    if (d.bits == 0 || d.bits > 64)
      Fail(where, std::to_string(d.bits) + " bits per sample is impossible");
    d.tile_count = d.tiled ? TIFFNumberOfTiles(tif) : TIFFNumberOfStrips(tif);
    for (uint64_t i = 0; i < d.tile_count; ++i) {
      int err = 0;
      const uint64_t off = TIFFGetStrileOffsetWithErr(tif, static_cast<uint32_t>(i), &err);
      const uint64_t len = TIFFGetStrileByteCountWithErr(tif, static_cast<uint32_t>(i), &err);
      if (err) Fail(where, "tile index is unreadable: " + file->TakeError());
      if (len == 0) {
        ++d.missing_tiles;  // sparse tile: GDAL writes these for empty areas
        continue;
      }
      if (off > s.file_size || len > s.file_size - off)
        Fail(where, std::string(d.tiled ? "tile " : "strip ") + std::to_string(i) +
                        " lies past the end of the file (bytes " + std::to_string(off) + ".." +
                        std::to_string(off + len) + " of " + std::to_string(s.file_size) +
                        "): the file is truncated");
      d.compressed_bytes += len;
    }
    s.directories.push_back(d);
    ++index;
  } while (TIFFReadDirectory(tif));
  const std::string late = file->TakeError();
  if (s.directories.empty()) Fail(path, "no image directory" + (late.empty() ? "" : ": " + late));
  // A broken link to a later directory is an error, not a silently shorter pyramid.
  if (!late.empty() && late.find("Sanity check") == std::string::npos &&
      late.find("IFD looping") == std::string::npos)
    Fail(path + " (IFD " + std::to_string(index) + ")", late);

  // Levels: the first non-mask image, then reduced-resolution images that shrink each time.
  for (const auto& d : s.directories) {
    if (d.is_mask) continue;
    if (s.levels.empty()) {
      s.levels.push_back(d.index);
      continue;
    }
    const auto& prev = s.directories[s.levels.back()];
    if ((d.subfile_type & FILETYPE_REDUCEDIMAGE) && d.width < prev.width &&
        d.height <= prev.height && d.samples == prev.samples && d.bits == prev.bits)
      s.levels.push_back(d.index);
  }
  if (s.levels.empty()) Fail(path, "holds only mask images");
  for (int level : s.levels) {
    const auto& l = s.directories[size_t(level)];
    int found = -1;
    for (const auto& d : s.directories)
      if (found < 0 && d.is_mask && d.width == l.width && d.height == l.height && d.samples == 1 && d.bits == 1 &&
          ((d.subfile_type & FILETYPE_REDUCEDIMAGE) != 0) == (level != s.levels[0]))
        found = d.index;
    s.masks.push_back(found);
  }
  return s;
}

}  // namespace rolamos
