#include "rolamos/tile_cache.hpp"

#include <OpenImageIO/imagecache.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <mutex>

#include "rolamos/error.hpp"
#include "raster/decoded_tiles.h"

namespace rolamos {

bool TileCacheOptions::IsValid(std::string* error) const {
  if (!(max_memory_mb >= 1.0 && max_memory_mb <= 1024.0 * 1024.0)) {
    *error = "tile cache size " + std::to_string(max_memory_mb) + " MB is outside 1..1048576";
    return false;
  }
  if (max_open_files < 4) {
    *error = "the tile cache needs at least 4 open files";
    return false;
  }
  return true;
}

TileCache::TileCache(const TileCacheOptions& options) : options_(options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("tile cache", error);
  static std::once_flag once;
  std::call_once(once, [] {
    // OpenImageIO refuses TIFFs whose whole size passes this cap (32 GB by default), and a
    // full-resolution mosaic can: allow 1 TB. Allocations stay per tile, and tiff_inspect
    // refuses impossible tiles and sides before OpenImageIO sees the file.
    OIIO::attribute("limits:imagesize_MB", 1 << 20);
  });
  auto* ic = OIIO::ImageCache::create(/*shared=*/false);
  const double oiio_mb = std::max(1.0, options.max_memory_mb / 8);
  ic->attribute("max_memory_MB", static_cast<float>(oiio_mb));
  tiles_ = std::make_unique<DecodedTiles>(static_cast<size_t>((options.max_memory_mb - oiio_mb) * 1024 * 1024));
  ic->attribute("max_open_files", options.max_open_files);
  ic->attribute("autotile", 256);       // scanline images are served in 256-row tiles
  ic->attribute("autoscanline", 1);
  ic->attribute("accept_untiled", 1);
  ic->attribute("unassociatedalpha", 1);  // keep stored colours: no premultiplication on read
  ic->attribute("forcefloat", 0);
  ic->attribute("failure_retries", 0);
  ic->attribute("deduplicate", 0);
  cache_ = ic;
}

TileCache::~TileCache() {
  OIIO::ImageCache::destroy(static_cast<OIIO::ImageCache*>(cache_), /*teardown=*/true);
}

void TileCache::Invalidate(const std::string& path) {
  const std::string absolute = std::filesystem::absolute(path).lexically_normal().string();
  static_cast<OIIO::ImageCache*>(cache_)->invalidate(OIIO::ustring(absolute), true);
  tiles_->Forget(absolute);
}

std::string TileCache::Stats(int level) const {
  return tiles_->Stats() + static_cast<OIIO::ImageCache*>(cache_)->getstats(level);
}

std::shared_ptr<TileCache> DefaultTileCache() {
  static std::mutex mutex;
  static std::weak_ptr<TileCache> shared;
  std::lock_guard<std::mutex> lock(mutex);
  auto cache = shared.lock();
  if (!cache) {
    TileCacheOptions o;
    if (const char* mb = std::getenv("ROLAMOS_CACHE_MB")) o.max_memory_mb = std::atof(mb);
    cache = std::make_shared<TileCache>(o);
    shared = cache;
  }
  return cache;
}

}  // namespace rolamos
