// A bounded cache of decoded tiles shared by every reader. Tiled TIFFs (ours, GDAL's, COGs) are
// decoded by libtiff into a cache of our own; other images go through OpenImageIO's ImageCache.
// The memory limit is an explicit number, shared: 7/8 for the TIFF tiles, 1/8 (at least 1 MB)
// for OpenImageIO's; nothing reads tiles outside them.
#pragma once

#include <memory>
#include <string>

namespace rolamos {

class DecodedTiles;

struct TileCacheOptions {
  double max_memory_mb = 256.0;
  int max_open_files = 64;

  bool IsValid(std::string* error) const;
};

class TileCache {
 public:
  explicit TileCache(const TileCacheOptions& options = {});
  ~TileCache();
  TileCache(const TileCache&) = delete;
  TileCache& operator=(const TileCache&) = delete;

  const TileCacheOptions& options() const { return options_; }
  // Forgets a file (after it was rewritten).
  void Invalidate(const std::string& path);
  // Cache statistics as OpenImageIO prints them (level 1..5).
  std::string Stats(int level = 1) const;

 private:
  friend class TiledImage;  // reads through the OpenImageIO cache underneath
  TileCacheOptions options_;
  void* cache_ = nullptr;   // OIIO::ImageCache*; OpenImageIO stays out of the public headers
  std::unique_ptr<DecodedTiles> tiles_;  // what libtiff decoded
};

}  // namespace rolamos
