// Tiles of a tiled TIFF decoded by libtiff directly (libjpeg-turbo, zstd, deflate, WebP, LZW),
// for TiledImage's reads of our BigTIFFs and of GDAL's tiled TIFFs and COGs. OpenImageIO's cache
// costs 0.7 ms a 256 x 256 JPEG tile where libtiff alone takes 0.25 (bench/RESULTS.md): its
// bookkeeping, page faults and copies, and one decode at a time per file.
#pragma once

#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "raster/decoded_tiles.h"
#include "raster/tiff_file.h"
#include "raster/tiff_inspect.h"

namespace rolamos {

class TiffTileReader {
 public:
  // A reader when every level of `s` is tiled, interleaved, and in a colour model the file's own
  // samples give as stored (grey, RGB(A), or JPEG's YCbCr returned as RGB); else none.
  static std::unique_ptr<TiffTileReader> TryOpen(const std::string& path, const TiffStructure& s);
  ~TiffTileReader();

  // Tile (tx, ty) of level `level`, whole (the edge tiles' padding included), in the file's
  // channel order; 8 or 16-bit. Where every level has a transparency mask (and the samples no
  // alpha), the mask comes as an alpha sample after the others: 255 where it is set, else 0. A tile the file does not hold (sparse) is zeros. Throws Error
  // naming the file, level and tile when libtiff cannot decode it. Any thread.
  cv::Mat DecodeTile(int level, int tx, int ty) const;
  const FileStamp& stamp() const { return stamp_; }
  int tile_width(int level) const { return levels_[size_t(level)].tile_width; }
  // Samples a decoded tile has (the file's, plus one for the mask's alpha).
  int channels() const { return samples_ + (masked_ ? 1 : 0); }
  bool masked() const { return masked_; }
  int tile_height(int level) const { return levels_[size_t(level)].tile_height; }

 private:
  struct Level {
    int directory = 0;
    int tile_width = 0, tile_height = 0;
    long long width = 0, height = 0;
    bool jpeg_ycbcr = false;  // decoded as RGB by libjpeg
    int mask_directory = -1;
  };
  // libtiff's handles are one thread's at a time: each decode borrows one, set to the level's
  // directory. The first is opened with the reader, more on demand (at most kMaxHandles); when
  // one cannot be opened (the file was deleted or replaced since: a live preview superseded, a
  // mosaic composed anew), the decode waits for one already open, which still reads the file
  // as it was.
  struct Handle {
    std::unique_ptr<TiffFile> file;
    int directory = -1;
  };
  static constexpr size_t kMaxHandles = 8;
  std::unique_ptr<Handle> OpenHandle() const;
  std::unique_ptr<Handle> Borrow(int directory) const;
  // Tile (tx, ty) of `directory` into `out` (sized for it); a tile the file does not hold stays
  // as it is.
  void ReadTile(int directory, bool jpeg_ycbcr, int tx, int ty, cv::Mat& out, const std::string& what) const;
  void Return(std::unique_ptr<Handle> h) const;
  // A borrowed handle, given back however the decode ends.
  struct Lease {
    const TiffTileReader* reader;
    std::unique_ptr<Handle> handle;
    ~Lease() {
      if (handle) reader->Return(std::move(handle));
    }
  };

  std::string path_;
  // The file as its first handle opened it: a handle opened later on a file replaced meanwhile is
  // refused, and the cache keys its tiles by it.
  FileStamp stamp_;
  int samples_ = 0, bits_ = 8;
  bool masked_ = false;
  std::vector<Level> levels_;
  mutable std::mutex mutex_;
  mutable std::condition_variable returned_;
  mutable std::vector<std::unique_ptr<Handle>> idle_;
  mutable size_t open_ = 0;  // handles open: idle or borrowed
};

}  // namespace rolamos
