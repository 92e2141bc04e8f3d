// A bounded cache of decoded tiles shared by every reader (OpenImageIO's ImageCache underneath).
// Its memory limit is an explicit number: nothing reads tiles outside it.
#pragma once

#include <memory>
#include <string>

namespace rolamos {

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
};

}  // namespace rolamos
