// Compresses single tiles with libtiff's own codecs, so a tile's bytes are exactly what libtiff
// would have written, but on any thread: each encoder drives a private in-memory TIFF whose
// tiles are emptied after every call (the GDAL approach to multi-threaded TIFF compression).
// WebP tiles are encoded by libwebp directly, the way libtiff's codec does (same preset, quality
// and lossless alpha), because libtiff offers no control over libwebp's effort.
#pragma once

#include <memory>
#include <mutex>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/image_format.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

class TiffFile;

class TileEncoder {
 public:
  // `mask`: the encoder of a transparency mask's tiles (SetMaskTags), fed packed bits:
  // tile_size rows of tile_size / 8 bytes, the leftmost pixel in the highest bit.
  TileEncoder(const PixelLayout& layout, const TiffWriteOptions& options, bool mask = false);
  ~TileEncoder();
  // `tile` is tile_size x tile_size, RGB(A)/gray order as the file stores it, contiguous.
  std::vector<uint8_t> Encode(const cv::Mat& tile);
  // JPEG only: the tables every tile's abbreviated stream refers to (the same for every
  // encoder of these options). Encodes a blank tile first if nothing was encoded yet.
  std::vector<uint8_t> JpegTables();

 private:
  void Reset();

  PixelLayout layout_;
  TiffWriteOptions options_;
  bool mask_ = false;
  std::unique_ptr<TiffFile> file_;
  uint32_t next_tile_ = 0;
  uint32_t capacity_ = 0;
  size_t header_size_ = 0;
};

// A thread-safe set of encoders: one per concurrent caller, created on demand.
class TileEncoderPool {
 public:
  TileEncoderPool(const PixelLayout& layout, const TiffWriteOptions& options, bool mask = false)
      : layout_(layout), options_(options), mask_(mask) {}
  std::vector<uint8_t> Encode(const cv::Mat& tile);
  std::vector<uint8_t> JpegTables();

 private:
  std::unique_ptr<TileEncoder> Take();
  void Give(std::unique_ptr<TileEncoder> encoder);

  PixelLayout layout_;
  TiffWriteOptions options_;
  bool mask_ = false;
  std::mutex mutex_;
  std::vector<std::unique_ptr<TileEncoder>> idle_;
};

// Cuts tile (tx, ty) out of `band` (whose row 0 is the tile row's first row), converts to file
// channel order, and pads to a full tile by repeating edge pixels (no seams in JPEG at edges).
cv::Mat CutFileTile(const cv::Mat& band, int tx, int tile_size);

}  // namespace rolamos
