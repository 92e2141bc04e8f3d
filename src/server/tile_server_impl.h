// The tile server's state and routes (rolamos/tile_server.hpp), shared by its parts: the image
// tiles, the viewer and the live API (tile_server.cc), and what GIS clients read (gis_routes.cc).
#pragma once

#include <httplib.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <thread>
#include <unordered_map>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "rolamos/tile_server.hpp"
#include "server/live_navigation.h"
#include "server/tile_pyramid.h"
#include "server/web_mercator.h"

namespace rolamos {

// One image the server offers, as found when it was added (a newer file is added anew).
struct ServedImage {
  std::string name, path;
  std::unique_ptr<TilePyramid> tiles;
  // Its Web Mercator tiles when the image is on Earth; otherwise why not.
  std::unique_ptr<WebMercatorTiles> mercator;
  std::string mercator_why;
  std::string version;    // changes when the file does: part of every ETag
  bool changing = false;  // the live preview: replaced every few seconds, never cached long
};

// Whole numbers of a URL (tile indices): at most 12 digits.
bool ParseIndex(const std::string& s, long long* out);

// Encoded tiles warped by GDAL (the costly ones), least recently used first out, within a byte
// budget.
class EncodedTileCache {
 public:
  explicit EncodedTileCache(size_t max_bytes) : max_bytes_(max_bytes) {}
  bool Get(const std::string& key, std::string* bytes);
  void Put(const std::string& key, std::string bytes);

 private:
  std::mutex mutex_;
  size_t max_bytes_, bytes_ = 0;
  std::list<std::pair<std::string, std::string>> order_;  // newest first
  std::unordered_map<std::string, std::list<std::pair<std::string, std::string>>::iterator> index_;
};

struct TileServer::Impl {
  explicit Impl(Store s) : store(std::move(s)) {}
  Store store;
  TileServerOptions options;
  std::shared_ptr<TileCache> cache;
  std::map<std::string, std::shared_ptr<const ServedImage>> images;
  // A store being written (mosaic --live): patches appear; Refresh adds them, and replaces the
  // open patch's preview ("live") as the engine rewrites it. Requests hold what they found.
  mutable std::shared_mutex images_mutex;
  nlohmann::json preview = {{"patch", 0}};  // live/preview.json as last read
  std::unique_ptr<LiveNavigation> navigation;  // a growing navigation CSV, when given
  std::mutex refresh_mutex;
  std::chrono::steady_clock::time_point refreshed{};
  httplib::Server http;
  std::thread thread;
  int port = 0;
  std::atomic<long long> exports{0};
  EncodedTileCache mercator_tiles{64u << 20};

  // A tile answered with its ETag (304 when the client has it), cut by `cut` (empty: 404 with
  // `outside`), encoded as `ext` over `background` (JPEG).
  void Reply(const httplib::Request& req, httplib::Response& res, const ServedImage& s, const std::string& key,
             const std::string& ext, const cv::Scalar& background, const std::function<cv::Mat()>& cut,
             const std::string& outside);
  void Add(const std::string& name, const std::string& path, bool changing = false);
  void RefreshPreview();
  void Refresh();
  std::shared_ptr<const ServedImage> Find(const std::string& name, httplib::Response& res) const;
  void Routes();     // all of them, in the order they are matched:
  void ApiRoutes();  // status, images
  void TileRoutes();  // XYZ, Deep Zoom
  void PageRoutes();  // the viewer
  void LiveAndExportRoutes();  // the live view, overlays, export, the error page
  void GisRoutes();  // Web Mercator tiles, TileJSON, WMTS, GDAL WMS descriptions, files with ranges
  void MercatorRoutes();   // of GisRoutes: the map page's config, Web Mercator tiles, TileJSON
  void WmtsRoutes();       // capabilities (RESTful and KVP), GetTile by KVP
  void GdalWmsRoutes();    // GDAL WMS descriptions of the XYZ and Web Mercator tiles
  void StoreFileRoutes();  // the store's files by their manifest names, with range requests
  // A Web Mercator tile of image `name` (the XYZ route's and WMTS GetTile's), cached encoded.
  void MercatorTile(const httplib::Request& req, httplib::Response& res, const std::string& name, long long z,
                    long long x, long long y, const std::string& ext);
};

}  // namespace rolamos
