#include "rolamos/tile_server.hpp"

#include <httplib.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <atomic>
#include <cstdio>
#include <chrono>
#include <mutex>
#include <shared_mutex>
#include <thread>

#include <unistd.h>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/tiled_image.hpp"
#include "server/live_navigation.h"
#include "server/live_view.h"
#include "server/overlays.h"
#include "server/tile_pyramid.h"
#include "server/tile_server_impl.h"
#include "server/viewer_assets.h"
#include "util/files.h"

namespace rolamos {

bool TileServerOptions::IsValid(std::string* error) const {
  if (port < 0 || port > 65535) {
    *error = "port " + std::to_string(port) + " is outside 0..65535";
    return false;
  }
  if (threads < 0 || threads > 256) {
    *error = "threads must be 0..256";
    return false;
  }
  if (!(max_export_megapixels > 0)) {
    *error = "the export limit must be positive";
    return false;
  }
  return TileEncodingIsValid(jpeg_quality, cache_mb, error);
}

namespace {

constexpr int kTile = TilePyramid::kTile;

// ?background=RRGGBB (hex): the colour JPEG tiles give "no data". False when malformed.
bool ParseBackground(const httplib::Request& req, cv::Scalar* bgr) {
  *bgr = cv::Scalar(0, 0, 0);
  if (!req.has_param("background")) return true;
  const std::string v = req.get_param_value("background");
  if (v.size() != 6 || v.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) return false;
  const long rgb = std::stol(v, nullptr, 16);
  *bgr = cv::Scalar(rgb & 255, (rgb >> 8) & 255, (rgb >> 16) & 255);
  return true;
}

}  // namespace

bool ParseIndex(const std::string& s, long long* out) {
  if (s.empty() || s.size() > 12) return false;
  for (char c : s)
    if (c < '0' || c > '9') return false;
  *out = std::stoll(s);
  return true;
}

bool EncodedTileCache::Get(const std::string& key, std::string* bytes) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = index_.find(key);
  if (it == index_.end()) return false;
  order_.splice(order_.begin(), order_, it->second);
  *bytes = it->second->second;
  return true;
}

void EncodedTileCache::Put(const std::string& key, std::string bytes) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (bytes.size() > max_bytes_ || index_.count(key)) return;
  bytes_ += bytes.size();
  order_.emplace_front(key, std::move(bytes));
  index_[key] = order_.begin();
  while (bytes_ > max_bytes_) {
    bytes_ -= order_.back().second.size();
    index_.erase(order_.back().first);
    order_.pop_back();
  }
}

void TileServer::Impl::Reply(const httplib::Request& req, httplib::Response& res, const ServedImage& s,
                             const std::string& key, const std::string& ext, const cv::Scalar& background,
                             const std::function<cv::Mat()>& cut, const std::string& outside) {
  char bg[16];
  std::snprintf(bg, sizeof bg, "%02x%02x%02x", int(background[2]), int(background[1]), int(background[0]));
  const std::string etag = "\"" + s.version + "-" + key + "." + ext + (ext == "jpg" ? std::string("-") + bg : "") + "\"";
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", s.changing ? "no-cache" : "public, max-age=3600");
  if (req.get_header_value("If-None-Match") == etag) {
    res.status = 304;
    return;
  }
  cv::Mat tile;
  try {
    tile = cut();
  } catch (const Error& e) {
    res.status = 500;
    res.set_content(e.what(), "text/plain");
    return;
  }
  if (tile.empty()) {
    res.status = 404;
    res.set_content(outside + "\n", "text/plain");
    return;
  }
  const auto bytes = TilePyramid::Encode(tile, ext, options.jpeg_quality, background);
  res.set_content(std::string(bytes.begin(), bytes.end()),
                  ext == "png" ? "image/png" : ext == "webp" ? "image/webp" : "image/jpeg");
}

void TileServer::Impl::Add(const std::string& name, const std::string& path, bool changing) {
  auto s = std::make_shared<ServedImage>();
  s->name = name;
  s->path = path;
  s->changing = changing;
  s->tiles = std::make_unique<TilePyramid>(std::make_shared<TiledImage>(TiledImage::Open(path, cache)));
  // Web Mercator tiles for an image on Earth (the live preview moves: never).
  if (!changing) {
    try {
      s->mercator = WebMercatorTiles::Open(path, &s->mercator_why);
    } catch (const Error& e) {
      s->mercator_why = e.what();
    }
  } else {
    s->mercator_why = "the live preview is not georeferenced";
  }
  std::error_code ec;
  const auto t = std::filesystem::last_write_time(path, ec).time_since_epoch().count();
  s->version = std::to_string(t) + "-" + std::to_string(std::filesystem::file_size(path, ec));
  std::unique_lock<std::shared_mutex> lock(images_mutex);
  images[name] = std::move(s);
}

// The open patch's preview, when the engine has written a newer one (under refresh_mutex).
void TileServer::Impl::RefreshPreview() {
  const std::string file = store.dir() + "/live/preview.json";
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) return;
  nlohmann::json p;
  try {
    p = nlohmann::json::parse(ReadSmallFile(file, 16 << 20));
  } catch (const std::exception&) {
    return;  // being replaced: the next refresh reads it
  }
  const std::string image = p.value("image", "");
  std::string served;
  {
    std::shared_lock<std::shared_mutex> read(images_mutex);
    auto it = images.find("live");
    if (it != images.end()) served = it->second->path;
  }
  if (image.empty() || p.value("patch", 0) == 0) {
    std::unique_lock<std::shared_mutex> lock(images_mutex);
    images.erase("live");
    preview = p;
    return;
  }
  const std::string path = store.dir() + "/" + image;
  if (path != served) {
    if (image.find("..") != std::string::npos || image.rfind("live/preview-", 0) != 0) return;  // not the engine's
    try {
      Add("live", path, /*changing=*/true);
    } catch (const Error&) {
      return;  // removed meanwhile: a newer one is named by the next preview.json
    }
    if (!served.empty()) cache->Invalidate(served);
  }
  std::unique_lock<std::shared_mutex> lock(images_mutex);
  preview = p;
}

// New patches (and a mosaic) written since the server started, and the live preview; at most
// four times a second.
void TileServer::Impl::Refresh() {
  std::lock_guard<std::mutex> lock(refresh_mutex);
  const auto now = std::chrono::steady_clock::now();
  if (now - refreshed < std::chrono::milliseconds(250)) return;
  refreshed = now;
  try {
    for (const auto& [name, path] : StoreImages(Store::Open(store.dir()))) {
      {
        std::shared_lock<std::shared_mutex> read(images_mutex);
        if (images.count(name)) continue;
      }
      Add(name, path);
    }
  } catch (const Error&) {
    // A manifest being replaced, or a patch not yet readable: the next refresh sees it.
  }
  RefreshPreview();
}

std::shared_ptr<const ServedImage> TileServer::Impl::Find(const std::string& name, httplib::Response& res) const {
  std::shared_lock<std::shared_mutex> lock(images_mutex);
  auto it = images.find(name);
  if (it == images.end()) {
    res.status = 404;
    res.set_content("no such image (see /api/images)\n", "text/plain");
    return nullptr;
  }
  return it->second;
}

// What the store holds and what a live run last wrote.
void TileServer::Impl::ApiRoutes() {
  http.Get("/api/status", [this](const httplib::Request&, httplib::Response& res) {
    // What a live run (`mosaic --live`) last wrote; {"running": false} for a finished store.
    nlohmann::json st = {{"running", false}};
    const std::string path = store.dir() + "/live/status.json";
    std::error_code ec;
    if (std::filesystem::exists(path, ec)) {
      try {
        st = nlohmann::json::parse(ReadSmallFile(path, 1 << 20));
      } catch (const std::exception&) {
      }
    }
    Refresh();
    {
      std::shared_lock<std::shared_mutex> lock(images_mutex);
      st["images_served"] = images.size();
    }
    res.set_header("Cache-Control", "no-store");
    res.set_content(st.dump(), "application/json");
  });
  http.Get("/api/images", [this](const httplib::Request&, httplib::Response& res) {
    Refresh();
    nlohmann::json list = nlohmann::json::array();
    std::shared_lock<std::shared_mutex> lock(images_mutex);
    for (const auto& [name, s] : images) {
      nlohmann::json levels = nlohmann::json::array();
      const TiledImage& image = s->tiles->image();
      for (const auto& l : image.info().levels) levels.push_back({l.width, l.height});
      list.push_back({{"name", name}, {"width", image.width()}, {"height", image.height()},
                      {"levels", levels}, {"tile_size", kTile},
                      {"xyz", "/tiles/" + name + "/{z}/{x}/{y}.jpg"},
                      {"xyz_max_zoom", s->tiles->xyz_max_zoom()},
                      {"dzi", "/dzi/" + name + ".dzi"}, {"version", s->version}});
      if (s->changing) list.back()["changing"] = true;
      list.back()["gdal_wms"] = "/gdal/" + name + ".xml";
      if (s->mercator) {
        const auto& b = s->mercator->bounds_wgs84();
        list.back()["webmercator"] = {{"tiles", "/tiles/" + name + "/webmercator/{z}/{x}/{y}.png"},
                                      {"tilejson", "/tilejson/" + name + ".json"},
                                      {"gdal_wms", "/gdal/" + name + ".webmercator.xml"},
                                      {"min_zoom", s->mercator->min_zoom()},
                                      {"max_zoom", s->mercator->max_zoom()},
                                      {"bounds", {b[0], b[1], b[2], b[3]}}};
      }
    }
    res.set_content(list.dump(1), "application/json");
  });
}

// XYZ and Deep Zoom tiles of every image served.
void TileServer::Impl::TileRoutes() {
  // XYZ: z = 0 is the whole image within one tile; every tile 256 x 256 (the part past the image
  // transparent, or ?background=RRGGBB in JPEG), as XYZ clients expect.
  http.Get(R"(/tiles/([^/]+)/([^/]+)/([^/]+)/([^/.]+)\.([a-z]+))",
           [this](const httplib::Request& req, httplib::Response& res) {
             const auto s = Find(req.matches[1], res);
             if (!s) return;
             long long z, x, y;
             const std::string ext = req.matches[5];
             cv::Scalar background;
             if (!ParseIndex(req.matches[2], &z) || !ParseIndex(req.matches[3], &x) ||
                 !ParseIndex(req.matches[4], &y) || (ext != "jpg" && ext != "png" && ext != "webp") ||
                 !ParseBackground(req, &background)) {
               res.status = 400;
               res.set_content("expected /tiles/NAME/Z/X/Y.jpg|png|webp with whole numbers (and ?background=RRGGBB)\n",
                               "text/plain");
               return;
             }
             if (z > s->tiles->xyz_max_zoom()) {
               res.status = 404;
               res.set_content("zoom " + std::to_string(z) + " is beyond full resolution (" +
                               std::to_string(s->tiles->xyz_max_zoom()) + ")\n", "text/plain");
               return;
             }
             const std::string key = "xyz-" + std::to_string(z) + "-" + std::to_string(x) + "-" + std::to_string(y);
             Reply(req, res, *s, key, ext, background, [&] { return s->tiles->XyzTile(int(z), x, y); },
                   "tile " + std::to_string(x) + "," + std::to_string(y) + " is outside zoom " + std::to_string(z) +
                       "'s grid (0.." + std::to_string((1LL << std::min<long long>(z, 40)) - 1) + ")");
           });
  http.Get(R"(/dzi/([^/]+)\.dzi)", [this](const httplib::Request& req, httplib::Response& res) {
    const auto s = Find(req.matches[1], res);
    if (!s) return;
    // ?format=webp|png keeps the alpha (no data stays transparent: layers over one another).
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "jpg";
    if (format != "jpg" && format != "png" && format != "webp") {
      res.status = 400;
      res.set_content("format must be jpg, png or webp\n", "text/plain");
      return;
    }
    if (s->changing) res.set_header("Cache-Control", "no-cache");
    res.set_content(s->tiles->DziDescriptor(format), "application/xml");
  });
  http.Get(R"(/dzi/([^/]+)_files/([^/]+)/([^/_]+)_([^/.]+)\.([a-z]+))",
           [this](const httplib::Request& req, httplib::Response& res) {
             const auto s = Find(req.matches[1], res);
             if (!s) return;
             long long level, x, y;
             const std::string ext = req.matches[5];
             if (!ParseIndex(req.matches[2], &level) || !ParseIndex(req.matches[3], &x) ||
                 !ParseIndex(req.matches[4], &y) || (ext != "jpg" && ext != "png" && ext != "webp")) {
               res.status = 400;
               res.set_content("expected /dzi/NAME_files/LEVEL/X_Y.jpg|png|webp\n", "text/plain");
               return;
             }
             if (level > s->tiles->max_level()) {
               res.status = 404;
               res.set_content("level beyond full resolution\n", "text/plain");
               return;
             }
             cv::Scalar background;
             if (!ParseBackground(req, &background)) {
               res.status = 400;
               res.set_content("background must be RRGGBB (hex)\n", "text/plain");
               return;
             }
             const std::string key = "dzi-" + std::to_string(level) + "-" + std::to_string(x) + "-" + std::to_string(y);
             Reply(req, res, *s, key, ext, background, [&] { return s->tiles->Tile(int(level), x, y); },
                   "tile outside the image");
           });
}

// The viewer's own files, from the binary.
void TileServer::Impl::PageRoutes() {
  // The viewer page, from the binary.
  for (const ViewerAsset& a : ViewerAssets()) {
    const std::string path = a.path;
    auto serve = [a](const httplib::Request&, httplib::Response& res) {
      const std::string mime = a.mime;
      res.set_content(reinterpret_cast<const char*>(a.data), a.size,
                      mime.rfind("text/", 0) == 0 ? mime + "; charset=utf-8" : mime);
      res.set_header("Cache-Control", "no-cache");
    };
    http.Get("/" + path, serve);
    if (path == "index.html") http.Get("/", serve);
  }
}

// The live run's view, the overlays, the full-resolution export and the error page.
void TileServer::Impl::LiveAndExportRoutes() {
  // The live run's open patch and the patches it continues, placed together (server/live_view.h).
  http.Get("/api/live", [this](const httplib::Request&, httplib::Response& res) {
    Refresh();
    nlohmann::json p;
    std::string version;
    {
      std::shared_lock<std::shared_mutex> lock(images_mutex);
      p = preview;
      auto it = images.find("live");
      if (it != images.end()) version = it->second->version;
    }
    nlohmann::json view;
    try {
      const Store now = Store::Open(store.dir());
      std::map<std::string, FrameNavigation> nav;
      nlohmann::json nav_state = nullptr;
      if (navigation) {
        const auto size = p.value("frame_size", nlohmann::json::array());
        std::vector<std::string> warnings;
        try {
          if (size.size() == 2) nav = navigation->Read(now, cv::Size(size[0].get<int>(), size[1].get<int>()), &warnings);
          nav_state = {{"fixes", nav.size()}, {"lines_skipped", navigation->lines_skipped()}};
        } catch (const Error& e) {
          nav_state = {{"problem", e.what()}};
        }
        // Each bad line once, where the run is watched: the run goes on without it.
        for (const auto& w : warnings) std::fprintf(stderr, "rolamos: warning: navigation %s (line skipped)\n", w.c_str());
      }
      view = LiveView(now, p, 8, navigation ? &nav : nullptr);
      if (navigation) view["navigation"] = nav_state;
    } catch (const std::exception& e) {
      view = {{"patch", 0}, {"problem", e.what()}};
    }
    if (!view["preview"].is_null()) {
      view["preview"]["name"] = "live";
      view["preview"]["dzi"] = "/dzi/live.dzi";
      view["preview"]["version"] = version;
    }
    res.set_header("Cache-Control", "no-store");
    res.set_content(view.dump(), "application/json");
  });
  http.Get(R"(/api/overlays/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    const auto s = Find(req.matches[1], res);
    if (!s) return;
    // The store read afresh: a live run adds patches (and align replaces sidecars) meanwhile.
    res.set_content(ImageOverlays(Store::Open(store.dir()), s->name, s->path).dump(), "application/json");
  });
  // Full-resolution export of a region through the export code: ?region=x,y,w,h
  // [&scale=s][&format=png|jpg|tif]. Bounded, so a request cannot fill the disk or memory.
  http.Get(R"(/api/export/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    const auto s = Find(req.matches[1], res);
    if (!s) return;
    auto bad = [&](const std::string& why) {
      res.status = 400;
      res.set_content(why + "\n", "text/plain");
    };
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "png";
    if (format != "png" && format != "jpg" && format != "tif") return bad("format must be png, jpg or tif");
    double v[4] = {0, 0, 0, 0};
    const std::string region = req.get_param_value("region");
    if (std::sscanf(region.c_str(), "%lf,%lf,%lf,%lf", &v[0], &v[1], &v[2], &v[3]) != 4 || !(v[2] >= 1) ||
        !(v[3] >= 1) || !(v[0] >= 0) || !(v[1] >= 0))
      return bad("expected region=x,y,w,h in image pixels (w, h >= 1)");
    ExportOptions o;
    o.region = cv::Rect2d(v[0], v[1], v[2], v[3]);
    o.scale = req.has_param("scale") ? std::atof(req.get_param_value("scale").c_str()) : 1.0;
    if (!(o.scale > 0 && o.scale <= 1)) return bad("scale must be in (0, 1]");
    const double pixels = v[2] * v[3] * o.scale * o.scale;
    if (pixels > options.max_export_megapixels * 1e6)
      return bad("the export would be " + std::to_string(static_cast<long long>(pixels / 1e6)) +
                 " megapixels; this server allows " + std::to_string(static_cast<long long>(options.max_export_megapixels)) +
                 " (rolamos export has no limit)");
    const std::string file = (std::filesystem::temp_directory_path() /
                              ("rolamos-export-" + std::to_string(::getpid()) + "-" + std::to_string(++exports) + "." + format)).string();
    o.output = file;
    o.tiff.compression = Compression::kDeflate;
    try {
      ExportRegion(*s->tiles->image_ptr(), o);
      const std::string bytes = ReadSmallFile(file, 4ull << 30);
      std::filesystem::remove(file);
      res.set_header("Content-Disposition", "attachment; filename=\"" + s->name + "-" + std::to_string(static_cast<long long>(v[0])) +
                                                "-" + std::to_string(static_cast<long long>(v[1])) + "." + format + "\"");
      res.set_content(bytes, format == "png" ? "image/png" : format == "jpg" ? "image/jpeg" : "image/tiff");
    } catch (const Error& e) {
      std::error_code ec;
      std::filesystem::remove(file, ec);
      return bad(e.what());
    }
  });
  http.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (res.body.empty()) res.set_content("not found\n", "text/plain");
  });
}

void TileServer::Impl::Routes() {
  ApiRoutes();
  // Georeferenced tiles, TileJSON, WMTS and files first: their paths would also fit the pattern
  // below.
  GisRoutes();
  TileRoutes();
  PageRoutes();
  LiveAndExportRoutes();
}

TileServer::TileServer(Store store, const TileServerOptions& options)
    : impl_(std::make_unique<Impl>(store)) {
  std::string error;
  if (!options.IsValid(&error)) Fail("serve", error);
  Impl& m = *impl_;
  m.options = options;
  TileCacheOptions co;
  co.max_memory_mb = options.cache_mb;
  m.cache = std::make_shared<TileCache>(co);
  for (const auto& [name, path] : StoreImages(store)) m.Add(name, path);
  std::error_code ec;
  const bool live = options.live || std::filesystem::exists(store.dir() + "/live/status.json", ec);
  if (m.images.empty() && !live) Fail(store.dir(), "has no mosaic and no patches to serve");
  m.refreshed = std::chrono::steady_clock::now();
  if (!options.navigation.empty()) {
    LiveNavigationOptions no;
    no.csv = options.navigation;
    no.crs = options.navigation_crs;
    no.focal_px = options.focal_px;
    m.navigation = std::make_unique<LiveNavigation>(no);
  }
  m.Routes();
  // Browsers keep ~6 connections open per site and cpp-httplib holds a thread per open
  // connection: with fewer threads than that, a page waits on idle keep-alive sockets.
  const int threads = options.threads > 0
                          ? options.threads
                          : std::max(16, 4 * static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
  m.http.new_task_queue = [threads] { return new httplib::ThreadPool(static_cast<size_t>(threads)); };
  // Headers and body go out as separate writes: without this, delayed ACKs add ~40 ms a tile.
  m.http.set_tcp_nodelay(true);
}

TileServer::~TileServer() { Stop(); }

int TileServer::Start() {
  Impl& m = *impl_;
  if (m.options.port == 0) {
    m.port = m.http.bind_to_any_port(m.options.bind);
  } else {
    m.port = m.http.bind_to_port(m.options.bind, m.options.port) ? m.options.port : -1;
  }
  if (m.port <= 0)
    Fail(m.options.bind + ":" + std::to_string(m.options.port), "cannot listen there (in use, or not an address of this machine)");
  m.thread = std::thread([&m] { m.http.listen_after_bind(); });
  return m.port;
}

void TileServer::Stop() {
  if (!impl_) return;
  impl_->http.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

void TileServer::Wait() {
  if (impl_->thread.joinable()) impl_->thread.join();
}

}  // namespace rolamos
