#include "rolamos/stac_export.hpp"

#include <ogr_spatialref.h>
#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "raster/gdal_setup.h"
#include "rolamos/cog_export.hpp"
#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/tiled_image.hpp"
#include "util/files.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace rolamos {

bool StacOptions::IsValid(std::string* error) const {
  for (char c : id)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == '.')) {
      *error = "STAC id \"" + id + "\" may hold letters, digits, '-', '_' and '.' only";
      return false;
    }
  if (!datetime.empty() && datetime.find('/') == std::string::npos) {
    *error = "the time span \"" + datetime + "\" must be START/END (RFC 3339)";
    return false;
  }
  if (thumbnail_px < 16 || thumbnail_px > 4096) {
    *error = "thumbnail size " + std::to_string(thumbnail_px) + " is outside 16..4096";
    return false;
  }
  if (cog_quality < 1 || cog_quality > 100) {
    *error = "COG quality " + std::to_string(cog_quality) + " is outside 1..100";
    return false;
  }
  return true;
}

namespace {

std::string Rfc3339(std::time_t t) {
  char b[32];
  std::tm tm{};
  gmtime_r(&t, &tm);
  std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return b;
}

// An id from the store's directory name: letters, digits, '-', '_' and '.'.
std::string IdOf(const std::string& dir) {
  fs::path path = fs::path(dir).lexically_normal();
  if (path.filename().empty()) path = path.parent_path();
  std::string name = path.extension() == ".rolamos" ? path.stem().string() : path.filename().string();
  std::string id;
  for (char c : name) id += (std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == '.') ? c : '-';
  return id.empty() ? "survey" : id;
}

// The survey's time span: the frames' files' modification times, or the patches'.
std::pair<std::string, std::string> TimeSpan(const Store& store, std::string* source) {
  std::time_t first = 0, last = 0;
  auto see = [&](const std::string& path) {
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) return false;
    if (first == 0 || st.st_mtime < first) first = st.st_mtime;
    if (st.st_mtime > last) last = st.st_mtime;
    return true;
  };
  for (const auto& p : store.patches()) {
    try {
      for (const auto& f : store.ReadSidecar(p.id).frames) see(f.source);
    } catch (const Error&) {
    }
  }
  *source = "frame files";
  if (first == 0) {
    for (const auto& p : store.patches()) see((fs::path(store.dir()) / p.image).string());
    *source = "store";
  }
  if (first == 0) first = last = std::time(nullptr);
  return {Rfc3339(first), Rfc3339(last)};
}

// The covered ground: the alpha of a coarse level as polygons (outer rings and holes), in level-0
// pixels; the whole image when it has no alpha.
std::vector<std::vector<std::vector<cv::Point2d>>> CoveredPolygons(const TiledImage& image) {
  int level = 0;
  while (level + 1 < image.num_levels() &&
         std::max(image.info().levels[size_t(level)].width, image.info().levels[size_t(level)].height) > 1024)
    ++level;
  const auto& l = image.info().levels[size_t(level)];
  const double sx = double(image.width()) / double(l.width), sy = double(image.height()) / double(l.height);
  std::vector<std::vector<std::vector<cv::Point2d>>> polygons;
  if (!image.info().has_alpha) {
    polygons.push_back({{{0, 0}, {double(image.width()), 0}, {double(image.width()), double(image.height())},
                         {0, double(image.height())}}});
    return polygons;
  }
  const cv::Mat pixels = image.ReadRegion(level, cv::Rect(0, 0, int(l.width), int(l.height)));
  cv::Mat alpha, mask;
  cv::extractChannel(pixels, alpha, pixels.channels() - 1);
  mask = alpha > 0;
  cv::morphologyEx(mask, mask, cv::MORPH_CLOSE, cv::getStructuringElement(cv::MORPH_ELLIPSE, {5, 5}));
  std::vector<std::vector<cv::Point>> contours;
  std::vector<cv::Vec4i> hierarchy;
  cv::findContours(mask, contours, hierarchy, cv::RETR_CCOMP, cv::CHAIN_APPROX_SIMPLE);
  const double min_area = 1e-3 * double(l.width) * double(l.height);
  auto to_full = [&](const std::vector<cv::Point>& c) {
    std::vector<cv::Point> simple;
    cv::approxPolyDP(c, simple, 1.0, true);
    std::vector<cv::Point2d> ring;
    for (const auto& p : simple) ring.emplace_back((p.x + 0.5) * sx, (p.y + 0.5) * sy);
    return ring;
  };
  for (size_t i = 0; i < contours.size(); ++i) {
    if (hierarchy[i][3] >= 0 || std::fabs(cv::contourArea(contours[i])) < min_area) continue;  // outer rings only
    std::vector<std::vector<cv::Point2d>> polygon = {to_full(contours[i])};
    for (int h = hierarchy[i][2]; h >= 0; h = hierarchy[size_t(h)][0])
      if (std::fabs(cv::contourArea(contours[size_t(h)])) >= min_area) polygon.push_back(to_full(contours[size_t(h)]));
    if (polygon[0].size() >= 3) polygons.push_back(std::move(polygon));
  }
  return polygons;
}

// Twice the signed area of a ring (x east, y north): positive when counter-clockwise.
double SignedArea(const std::vector<std::array<double, 2>>& ring) {
  double a = 0;
  for (size_t i = 0; i + 1 < ring.size(); ++i) a += ring[i][0] * ring[i + 1][1] - ring[i + 1][0] * ring[i][1];
  return a;
}

}  // namespace

StacResult ExportStac(const Store& store, const std::string& dir, const StacOptions& options,
                      const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail(dir, error);
  if (!store.HasMosaic()) Fail(store.dir(), "has no mosaic.tif to catalogue (run rolamos compose first)");
  const TiledImage image = TiledImage::Open(store.MosaicPath());
  if (!image.info().georef) Fail(store.MosaicPath(), "is not georeferenced (compose --navigation places it on Earth)");
  const Georef& geo = *image.info().georef;
  EnsureGdal();
  OGRSpatialReference srs;
  if (srs.SetFromUserInput(geo.crs.c_str()) != OGRERR_NONE || srs.IsLocal() || !(srs.IsProjected() || srs.IsGeographic()))
    Fail(store.MosaicPath(), "is in a local frame, not on Earth: a catalogue needs a map CRS (compose --navigation)");
  srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  OGRSpatialReference wgs84;
  wgs84.SetWellKnownGeogCS("WGS84");
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> to_wgs84(OGRCreateCoordinateTransformation(&srs, &wgs84));
  if (!to_wgs84) Fail(store.MosaicPath(), "its CRS cannot be transformed to WGS 84: " + TakeGdalError());

  StacResult r;
  const std::string id = options.id.empty() ? IdOf(store.dir()) : options.id;
  const fs::path item_dir = fs::path(dir) / id;
  std::error_code ec;
  fs::create_directories(item_dir, ec);
  if (ec) Fail(item_dir.string(), "cannot be created: " + ec.message());

  // 1. The assets: the COG (GDAL's COG driver), a thumbnail.
  CogOptions cog;
  cog.quality = options.cog_quality;
  r.cog = (item_dir / (id + ".tif")).string();
  ExportCog(store.MosaicPath(), r.cog, cog, SubProgress(progress, 0.0, 0.8));
  ExportOptions thumb;
  thumb.scale = std::min(1.0, double(options.thumbnail_px) / double(std::max(image.width(), image.height())));
  thumb.output = r.thumbnail = (item_dir / (id + "-thumbnail.jpg")).string();
  ExportRegion(image, thumb, SubProgress(progress, 0.8, 0.9));

  // 2. The footprint in WGS 84 (RFC 7946: outer rings counter-clockwise, holes clockwise).
  const auto& g = geo.geotransform;
  json polygons = json::array();
  double west = 180, south = 90, east = -180, north = -90;
  for (const auto& polygon : CoveredPolygons(image)) {
    json rings = json::array();
    for (size_t k = 0; k < polygon.size(); ++k) {
      std::vector<double> xs, ys;
      for (const auto& p : polygon[k]) {
        xs.push_back(g[0] + p.x * g[1] + p.y * g[2]);
        ys.push_back(g[3] + p.x * g[4] + p.y * g[5]);
      }
      if (!to_wgs84->Transform(static_cast<int>(xs.size()), xs.data(), ys.data()))
        Fail(store.MosaicPath(), "its footprint cannot be transformed to WGS 84");
      std::vector<std::array<double, 2>> ring;
      for (size_t i = 0; i < xs.size(); ++i) ring.push_back({xs[i], ys[i]});
      ring.push_back(ring.front());
      if ((SignedArea(ring) < 0) == (k == 0)) std::reverse(ring.begin(), ring.end());
      json coords = json::array();
      for (const auto& p : ring) {
        coords.push_back({p[0], p[1]});
        west = std::min(west, p[0]), east = std::max(east, p[0]);
        south = std::min(south, p[1]), north = std::max(north, p[1]);
      }
      rings.push_back(coords);
    }
    polygons.push_back(rings);
  }
  if (polygons.empty()) Fail(store.MosaicPath(), "holds no data to outline");
  r.footprint_parts = static_cast<int>(polygons.size());
  const json geometry = polygons.size() == 1 ? json{{"type", "Polygon"}, {"coordinates", polygons[0]}}
                                             : json{{"type", "MultiPolygon"}, {"coordinates", polygons}};

  // 3. The properties: time span, ground sample distance, the projection extension's fields.
  std::string start, end;
  if (!options.datetime.empty()) {
    start = options.datetime.substr(0, options.datetime.find('/'));
    end = options.datetime.substr(options.datetime.find('/') + 1);
    r.time_source = "option";
  } else {
    std::tie(start, end) = TimeSpan(store, &r.time_source);
  }
  const double pixel = std::sqrt(std::fabs(g[1] * g[5] - g[2] * g[4]));
  const double gsd = srs.IsGeographic() ? pixel * 111320.0 * std::cos(0.5 * (south + north) * CV_PI / 180)
                                        : pixel * srs.GetLinearUnits();
  json properties = {{"title", options.title.empty() ? id : options.title},
                     {"datetime", nullptr},
                     {"start_datetime", start},
                     {"end_datetime", end},
                     {"created", Rfc3339(std::time(nullptr))},
                     {"gsd", gsd},
                     {"proj:shape", {image.height(), image.width()}},
                     {"proj:transform", {g[1], g[2], g[0], g[4], g[5], g[3]}},
                     {"rolamos:patches", store.patches().size()},
                     {"rolamos:frames", store.global().n_images},
                     {"rolamos:time_source", r.time_source}};
  const std::string code = CrsAuthorityCode(geo.crs);
  if (code.rfind("EPSG::", 0) == 0 && code.size() > 6 && code.find_first_not_of("0123456789", 6) == std::string::npos) {
    properties["proj:epsg"] = std::stoi(code.substr(6));
  } else {
    properties["proj:epsg"] = nullptr;
    char* wkt = nullptr;
    const char* wkt2[] = {"FORMAT=WKT2_2019", nullptr};
    srs.exportToWkt(&wkt, wkt2);
    properties["proj:wkt2"] = wkt ? wkt : "";
    CPLFree(wkt);
  }
  const json item = {
      {"type", "Feature"},
      {"stac_version", "1.0.0"},
      {"stac_extensions", {"https://stac-extensions.github.io/projection/v1.1.0/schema.json"}},
      {"id", id},
      {"geometry", geometry},
      {"bbox", {west, south, east, north}},
      {"properties", properties},
      {"links", {{{"rel", "root"}, {"href", "../catalog.json"}, {"type", "application/json"}},
                 {{"rel", "parent"}, {"href", "../catalog.json"}, {"type", "application/json"}}}},
      {"assets",
       {{"mosaic", {{"href", "./" + id + ".tif"}, {"type", "image/tiff; application=geotiff; profile=cloud-optimized"},
                    {"roles", {"data"}}, {"title", "Seafloor mosaic (Cloud Optimized GeoTIFF)"},
                    {"proj:shape", {image.height(), image.width()}}}},
        {"thumbnail", {{"href", "./" + id + "-thumbnail.jpg"}, {"type", "image/jpeg"}, {"roles", {"thumbnail"}},
                       {"title", "Overview"}}}}}};
  r.item = (item_dir / (id + ".json")).string();
  WriteFileAtomic(r.item, item.dump(2) + "\n");

  // 4. The catalogue: created, or the item added to (replacing one of the same id).
  r.catalog = (fs::path(dir) / "catalog.json").string();
  json catalog;
  if (fs::exists(r.catalog)) {
    std::ifstream in(r.catalog);
    catalog = json::parse(in, nullptr, false);
    if (catalog.is_discarded() || !catalog.is_object() || catalog.value("type", "") != "Catalog")
      Fail(r.catalog, "is not a STAC catalog; choose another directory");
  } else {
    catalog = {{"type", "Catalog"},
               {"stac_version", "1.0.0"},
               {"id", "rolamos-surveys"},
               {"title", "Seafloor surveys"},
               {"description", options.description.empty() ? "Seafloor maps made by rolamos" : options.description},
               {"links", {{{"rel", "root"}, {"href", "./catalog.json"}, {"type", "application/json"}}}}};
  }
  json links = json::array();
  const std::string href = "./" + id + "/" + id + ".json";
  for (const auto& l : catalog.value("links", json::array()))
    if (!(l.value("rel", "") == "item" && l.value("href", "") == href)) links.push_back(l);
  links.push_back({{"rel", "item"}, {"href", href}, {"type", "application/geo+json"}, {"title", properties["title"]}});
  catalog["links"] = links;
  WriteFileAtomic(r.catalog, catalog.dump(2) + "\n");
  if (progress) progress(1.0);
  return r;
}

}  // namespace rolamos
