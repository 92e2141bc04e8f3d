// `rolamos serve`: tiles of a store's mosaic and patches over HTTP, cut on demand from the
// pyramidal BigTIFFs through the bounded tile cache. Speaks XYZ (/tiles/NAME/Z/X/Y.jpg, Z = 0 is
// the whole image in one tile, for Leaflet/QGIS) and Deep Zoom (/dzi/NAME.dzi, for OpenSeadragon),
// with ETag/Cache-Control. Image names come from the store's manifest ("mosaic", "patch-N", and
// "live" for the open patch of a live run); no part of a URL is ever used as a file path.
#pragma once

#include <memory>
#include <string>

#include "rolamos/store.hpp"

namespace rolamos {

struct TileServerOptions {
  std::string bind = "127.0.0.1";  // loopback unless told otherwise
  int port = 8080;                 // 0: any free port
  int threads = 0;                 // 0: 4 per core, at least 16 (browsers hold ~6 connections)
  double cache_mb = 256;
  int jpeg_quality = 85;
  double max_export_megapixels = 256;  // largest export the page may ask for
  // The store is being written (mosaic --live --serve): it may have nothing to serve yet; patches
  // and the open patch's preview ("live", /api/live) are served as they appear.
  bool live = false;
  // A vehicle navigation CSV that grows during a live run (compose --navigation's columns): the
  // live view is georeferenced from it as it arrives. `navigation_crs` for eastings/northings
  // without an epsg column; `focal_px` 0: the store's camera.
  std::string navigation, navigation_crs;
  double focal_px = 0;
  // The base map the map page (/map.html) shows under the georeferenced images: an XYZ URL
  // template ({z}/{x}/{y}); "" = none (nothing is fetched from elsewhere unless asked).
  std::string basemap, basemap_attribution;
  int basemap_max_zoom = 19;

  bool IsValid(std::string* error) const;
};

class TileServer {
 public:
  // Opens every image of the store; throws Error when the store or an option is bad.
  TileServer(Store store, const TileServerOptions& options);
  ~TileServer();
  TileServer(const TileServer&) = delete;
  TileServer& operator=(const TileServer&) = delete;

  // Binds and serves in a background thread; returns the port. Throws Error if it cannot bind.
  int Start();
  void Stop();
  // Blocks until Stop() (from another thread or a signal handler).
  void Wait();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rolamos
