// What GIS clients ask `rolamos serve` for: Web Mercator tiles of georeferenced images (warped by
// GDAL, cached encoded), TileJSON, WMTS capabilities and GetTile by KVP, GDAL WMS descriptions of
// the XYZ tiles, and the store's files with range requests. Names in URLs are looked up in the
// server's images or the store's manifest; no URL part is ever used as a path.
#include <filesystem>
#include <map>

#include "rolamos/error.hpp"
#include "server/file_range.h"
#include "server/gis_documents.h"
#include "server/tile_server_impl.h"

namespace rolamos {

namespace {

// "http://HOST:PORT" as the client reached us: the documents' links point back the same way.
std::string BaseUrl(const httplib::Request& req, int port) {
  const std::string host = req.get_header_value("Host");
  return "http://" + (host.empty() ? "127.0.0.1:" + std::to_string(port) : host);
}

void Bad(httplib::Response& res, int status, const std::string& why) {
  res.status = status;
  res.set_content(why + "\n", "text/plain");
}

void OgcBad(httplib::Response& res, const std::string& code, const std::string& locator, const std::string& why) {
  res.status = 400;
  res.set_content(OgcException(code, locator, why), "application/xml");
}

// KVP parameters are case-insensitive in their names (OGC 06-121r9): the value of `name`.
std::string Kvp(const httplib::Request& req, const std::string& name) {
  for (const auto& [k, v] : req.params) {
    if (k.size() != name.size()) continue;
    bool same = true;
    for (size_t i = 0; i < k.size() && same; ++i) same = std::toupper(static_cast<unsigned char>(k[i])) == name[i];
    if (same) return v;
  }
  return "";
}

}  // namespace

void TileServer::Impl::GisRoutes() {
  MercatorRoutes();
  WmtsRoutes();
  GdalWmsRoutes();
  StoreFileRoutes();
}

// Web Mercator tiles: /tiles/NAME/webmercator/Z/X/Y.png|jpg|webp (?background=RRGGBB for JPEG).
void TileServer::Impl::MercatorTile(const httplib::Request& req, httplib::Response& res, const std::string& name,
                                    long long z, long long x, long long y, const std::string& ext) {
  const auto s = Find(name, res);
  if (!s) return;
  if (!s->mercator) return Bad(res, 404, name + " has no Web Mercator tiles: " + s->mercator_why);
  cv::Scalar background(0, 0, 0);
  if (req.has_param("background")) {
    const std::string v = req.get_param_value("background");
    if (v.size() != 6 || v.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos)
      return Bad(res, 400, "background must be RRGGBB (hex)");
    const long rgb = std::stol(v, nullptr, 16);
    background = cv::Scalar(rgb & 255, (rgb >> 8) & 255, (rgb >> 16) & 255);
  }
  if (!s->mercator->InGrid(int(std::min(z, 99LL)), x, y))
    return Bad(res, 404, "tile " + std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y) +
                             " is outside the Web Mercator grid (zoom 0..30, x and y below 2^zoom)");
  if (z > s->mercator->max_zoom())
    return Bad(res, 404, "zoom " + std::to_string(z) + " is finer than the map (" +
                             std::to_string(s->mercator->max_zoom()) + " is its full resolution)");
  const std::string key = "merc-" + std::to_string(z) + "-" + std::to_string(x) + "-" + std::to_string(y);
  // The warped tiles cost most: kept encoded (a recomposed image has a new version).
  std::string bytes;
  const std::string cache_key = s->name + "/" + s->version + "/" + key + "." + ext + "/" +
                                std::to_string(int(background[0])) + "," + std::to_string(int(background[1])) +
                                "," + std::to_string(int(background[2]));
  if (mercator_tiles.Get(cache_key, &bytes)) {
    res.set_header("ETag", "\"" + s->version + "-" + key + "." + ext + "\"");
    res.set_header("Cache-Control", "public, max-age=3600");
    res.set_content(bytes, ext == "png" ? "image/png" : ext == "webp" ? "image/webp" : "image/jpeg");
    return;
  }
  Reply(req, res, *s, key, ext, background, [&] { return s->mercator->Tile(int(z), x, y); }, "outside the grid");
  if ((res.status == 200 || res.status == -1) && !res.body.empty()) mercator_tiles.Put(cache_key, res.body);
}

void TileServer::Impl::MercatorRoutes() {
  // What the map page needs to know: the base map, when one was configured.
  http.Get("/api/config", [this](const httplib::Request&, httplib::Response& res) {
    nlohmann::json c = {{"basemap", options.basemap.empty() ? nlohmann::json(nullptr) : nlohmann::json(options.basemap)},
                        {"basemap_attribution", options.basemap_attribution},
                        {"basemap_max_zoom", options.basemap_max_zoom}};
    res.set_header("Cache-Control", "no-store");
    res.set_content(c.dump(), "application/json");
  });

  // Web Mercator tiles by XYZ.
  http.Get(R"(/tiles/([^/]+)/webmercator/([^/]+)/([^/]+)/([^/.]+)\.([a-z]+))",
           [this](const httplib::Request& req, httplib::Response& res) {
             long long z, x, y;
             const std::string ext = req.matches[5];
             if (!ParseIndex(req.matches[2], &z) || !ParseIndex(req.matches[3], &x) ||
                 !ParseIndex(req.matches[4], &y) || (ext != "jpg" && ext != "png" && ext != "webp"))
               return Bad(res, 400, "expected /tiles/NAME/webmercator/Z/X/Y.jpg|png|webp with whole numbers");
             MercatorTile(req, res, req.matches[1], z, x, y, ext);
           });

  // TileJSON 3.0.0 of the Web Mercator tiles.
  http.Get(R"(/tilejson/([^/]+)\.json)", [this](const httplib::Request& req, httplib::Response& res) {
    const auto s = Find(req.matches[1], res);
    if (!s) return;
    if (!s->mercator) return Bad(res, 404, s->name + " has no Web Mercator tiles: " + s->mercator_why);
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "png";
    if (format != "png" && format != "jpg" && format != "webp") return Bad(res, 400, "format must be png, jpg or webp");
    const std::string url = BaseUrl(req, port) + "/tiles/" + s->name + "/webmercator/{z}/{x}/{y}." + format;
    res.set_content(TileJson({s->name, s->mercator.get()}, url).dump(1), "application/json");
  });
}

void TileServer::Impl::WmtsRoutes() {
  // WMTS: the capabilities (RESTful and KVP) and GetTile by KVP.
  auto capabilities = [this](const httplib::Request& req, httplib::Response& res) {
    Refresh();
    std::vector<std::shared_ptr<const ServedImage>> hold;
    std::vector<GisLayer> layers;
    {
      std::shared_lock<std::shared_mutex> lock(images_mutex);
      for (const auto& [name, s] : images)
        if (s->mercator) {
          hold.push_back(s);
          layers.push_back({name, s->mercator.get()});
        }
    }
    if (layers.empty())
      return OgcBad(res, "LayerNotDefined", "layer",
                    "no image of this store is georeferenced (compose --navigation places the mosaic on Earth)");
    res.set_content(WmtsCapabilities(layers, BaseUrl(req, port)), "application/xml");
  };
  http.Get("/wmts/1.0.0/WMTSCapabilities.xml", capabilities);
  http.Get("/wmts", [this, capabilities](const httplib::Request& req, httplib::Response& res) {
    const std::string service = Kvp(req, "SERVICE"), request = Kvp(req, "REQUEST");
    if (service != "WMTS") return OgcBad(res, "MissingParameterValue", "service", "SERVICE=WMTS is required");
    if (request == "GetCapabilities") return capabilities(req, res);
    if (request != "GetTile")
      return OgcBad(res, "OperationNotSupported", "request",
                    "REQUEST=" + request + " is not served (GetCapabilities and GetTile are)");
    const std::string layer = Kvp(req, "LAYER"), format = Kvp(req, "FORMAT");
    long long z, row, col;
    if (layer.empty()) return OgcBad(res, "MissingParameterValue", "layer", "LAYER is required");
    if (!ParseIndex(Kvp(req, "TILEMATRIX"), &z) || !ParseIndex(Kvp(req, "TILEROW"), &row) ||
        !ParseIndex(Kvp(req, "TILECOL"), &col))
      return OgcBad(res, "InvalidParameterValue", "tilematrix",
                    "TILEMATRIX, TILEROW and TILECOL must be whole numbers");
    const std::string ext = format == "image/jpeg" ? "jpg" : format == "image/png" || format.empty() ? "png" : "";
    if (ext.empty()) return OgcBad(res, "InvalidParameterValue", "format", "FORMAT must be image/png or image/jpeg");
    MercatorTile(req, res, layer, z, col, row, ext);
  });
}

void TileServer::Impl::GdalWmsRoutes() {
  // GDAL WMS descriptions (TMS minidriver): `gdalinfo http://HOST/gdal/NAME.xml` or in QGIS.
  http.Get(R"(/gdal/([^/]+)\.xml)", [this](const httplib::Request& req, httplib::Response& res) {
    std::string name = req.matches[1];
    const std::string suffix = ".webmercator";
    const bool mercator = name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
    if (mercator) name.resize(name.size() - suffix.size());
    const auto s = Find(name, res);
    if (!s) return;
    const std::string base = BaseUrl(req, port);
    long long zoom = -1;
    if (req.has_param("zoom") && !ParseIndex(req.get_param_value("zoom"), &zoom))
      return Bad(res, 400, "zoom must be a whole number");
    if (mercator) {
      if (!s->mercator) return Bad(res, 404, name + " has no Web Mercator tiles: " + s->mercator_why);
      if (zoom > s->mercator->max_zoom()) return Bad(res, 404, "zoom " + std::to_string(zoom) + " is finer than the map");
      res.set_content(GdalWmsWebMercator(*s->mercator, base + "/tiles/" + name + "/webmercator/${z}/${x}/${y}.png",
                                         int(zoom)),
                      "application/xml");
      return;
    }
    if (zoom > s->tiles->xyz_max_zoom()) return Bad(res, 404, "zoom " + std::to_string(zoom) + " is finer than the map");
    res.set_content(GdalWmsPixel(*s->tiles, base + "/tiles/" + name + "/${z}/${x}/${y}.png", int(zoom)),
                    "application/xml");
  });
}

void TileServer::Impl::StoreFileRoutes() {
  // The store's files, by the names its manifest gives them: mosaic.tif, patches/NNNNNN.tif and
  // the exports recorded there (a COG `rolamos export --cog` wrote inside the store).
  http.Get(R"(/files/(.+))", [this](const httplib::Request& req, httplib::Response& res) {
    const std::string name = req.matches[1];
    std::map<std::string, std::string> files;
    try {
      const Store now = Store::Open(store.dir());
      if (now.HasMosaic()) files["mosaic.tif"] = now.MosaicPath();
      for (const auto& p : now.patches()) files[p.image] = (std::filesystem::path(now.dir()) / p.image).string();
      for (const auto& e : now.exports()) files[e.path] = (std::filesystem::path(now.dir()) / e.path).string();
    } catch (const Error& e) {
      return Bad(res, 503, std::string("the store cannot be read now: ") + e.what());
    }
    auto it = files.find(name);
    if (it == files.end()) {
      std::string known;
      for (const auto& [k, v] : files) known += (known.empty() ? "" : ", ") + k;
      return Bad(res, 404, "no file \"" + name + "\" in the store's manifest (" + (known.empty() ? "none" : known) + ")");
    }
    ServeFileRanges(it->second, "image/tiff", req, res);
  });
}

}  // namespace rolamos
