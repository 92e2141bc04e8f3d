#include "rolamos/tile_export.hpp"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "rolamos/error.hpp"
#include "server/gis_documents.h"
#include "server/overlays.h"
#include "server/tile_pyramid.h"
#include "server/viewer_assets.h"
#include "util/files.h"

namespace fs = std::filesystem;

namespace rolamos {

bool TileExportOptions::IsValid(std::string* error) const {
  if (format != "dzi" && format != "xyz") {
    *error = "tile format \"" + format + "\" is not dzi or xyz";
    return false;
  }
  if (ext != "jpg" && ext != "png" && ext != "webp") {
    *error = "tile encoding \"" + ext + "\" is not jpg, png or webp";
    return false;
  }
  return TileEncodingIsValid(jpeg_quality, cache_mb, error);
}

namespace {

void WriteBytes(const fs::path& path, const std::vector<uchar>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!out) Fail(path.string(), "cannot be written");
}

// The tiles of zoom z that touch the map: (x0, y0, x1, y1), inclusive.
std::array<long long, 4> TouchingRange(const WebMercatorTiles& m, int z) {
  const double size = 2 * WebMercatorTiles::kHalfWorld / std::ldexp(1.0, z);
  const auto& b = m.bounds_3857();
  const long long last = (1LL << z) - 1;
  auto clamp = [&](double v) { return std::clamp(static_cast<long long>(std::floor(v)), 0LL, last); };
  return {clamp((b[0] + WebMercatorTiles::kHalfWorld) / size), clamp((WebMercatorTiles::kHalfWorld - b[3]) / size),
          clamp((b[2] + WebMercatorTiles::kHalfWorld) / size), clamp((WebMercatorTiles::kHalfWorld - b[1]) / size)};
}

long long CountTouching(const WebMercatorTiles& m, int z) {
  const auto r = TouchingRange(m, z);
  return (r[2] - r[0] + 1) * (r[3] - r[1] + 1);
}

// Every Web Mercator tile of the map, zoom by zoom, into DIR/Z/X/Y.EXT (warped by GDAL on every
// core). Returns how many.
long long WriteWebMercator(const WebMercatorTiles& m, const fs::path& dir, const std::string& ext, int quality,
                           const cv::Scalar& background, const std::function<void(long long)>& on_tiles) {
  long long written = 0;
  for (int z = m.min_zoom(); z <= m.max_zoom(); ++z) {
    const auto r = TouchingRange(m, z);
    const long long nx = r[2] - r[0] + 1, ny = r[3] - r[1] + 1;
    for (long long x = r[0]; x <= r[2]; ++x) fs::create_directories(dir / std::to_string(z) / std::to_string(x));
    std::atomic<long long> n{0};
    cv::parallel_for_(cv::Range(0, static_cast<int>(nx * ny)), [&](const cv::Range& range) {
      for (int k = range.start; k < range.end; ++k) {
        const long long x = r[0] + k % nx, y = r[1] + k / nx;
        const auto bytes = TilePyramid::Encode(m.Tile(z, x, y), ext, quality, background);
        WriteBytes(dir / std::to_string(z) / std::to_string(x) / (std::to_string(y) + "." + ext), bytes);
        ++n;
      }
    });
    written += n;
    if (on_tiles) on_tiles(written);
  }
  return written;
}

}  // namespace

TileExportResult ExportTiles(Store store, const std::string& dir, const TileExportOptions& options,
                             const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("tiles", error);
  std::error_code ec;
  if (fs::exists(dir, ec)) Fail(dir, "exists already; tiles go into a new directory");
  TileCacheOptions co;
  co.max_memory_mb = options.cache_mb;
  auto cache = std::make_shared<TileCache>(co);
  const auto images = StoreImages(store);
  if (images.empty()) Fail(store.dir(), "has no mosaic and no patches to export");

  const fs::path tmp = TemporarySibling(fs::absolute(dir).lexically_normal().string());
  fs::create_directories(tmp, ec);
  if (ec) Fail(dir, "cannot be created: " + ec.message());
  TileExportResult result;
  try {
    std::vector<TilePyramid> pyramids;
    long long total = 0;
    for (const auto& [name, path] : images) {
      pyramids.emplace_back(std::make_shared<TiledImage>(TiledImage::Open(path, cache)));
      const auto& t = pyramids.back();
      for (int level = options.format == "xyz" ? t.xyz_shift() : 0; level <= t.max_level(); ++level) {
        const cv::Size s = t.LevelSize(level);
        total += static_cast<long long>((s.width + 255) / 256) * ((s.height + 255) / 256);
      }
    }
    // Web Mercator grids of the georeferenced images (xyz only).
    std::vector<std::unique_ptr<WebMercatorTiles>> mercators(images.size());
    if (options.format == "xyz") {
      for (size_t i = 0; i < images.size(); ++i) {
        std::string why;
        mercators[i] = WebMercatorTiles::Open(images[i].second, &why);
        if (!mercators[i]) continue;
        for (int z = mercators[i]->min_zoom(); z <= mercators[i]->max_zoom(); ++z) total += CountTouching(*mercators[i], z);
      }
    }
    const std::string base = options.base_url.empty() ? "file://" + fs::absolute(dir).lexically_normal().string()
                                                      : options.base_url;
    const cv::Scalar background(options.background[0], options.background[1], options.background[2]);
    nlohmann::json index = nlohmann::json::array();
    std::vector<GisLayer> layers;
    std::atomic<long long> done{0};
    for (size_t i = 0; i < images.size(); ++i) {
      const std::string& name = images[i].first;
      const TilePyramid& t = pyramids[i];
      const bool dzi = options.format == "dzi";
      if (dzi) {
        std::ofstream(tmp / (name + ".dzi")) << t.DziDescriptor(options.ext);
      }
      for (int level = dzi ? 0 : t.xyz_shift(); level <= t.max_level(); ++level) {
        const cv::Size s = t.LevelSize(level);
        const int nx = (s.width + 255) / 256, ny = (s.height + 255) / 256;
        const int z = level - t.xyz_shift();
        const fs::path level_dir = dzi ? tmp / (name + "_files") / std::to_string(level) : tmp / name / std::to_string(z);
        for (int x = 0; x < nx && !dzi; ++x) fs::create_directories(level_dir / std::to_string(x));
        if (dzi) fs::create_directories(level_dir);
        cv::parallel_for_(cv::Range(0, nx * ny), [&](const cv::Range& r) {
          for (int k = r.start; k < r.end; ++k) {
            const int x = k % nx, y = k / nx;
            // XYZ tiles whole (256 x 256, the part past the image without data), as every XYZ client
            // expects; Deep Zoom's edge tiles cut to the image, its own convention.
            const cv::Mat tile = dzi ? t.Tile(level, x, y) : t.XyzTile(z, x, y);
            const auto bytes = TilePyramid::Encode(tile, options.ext, options.jpeg_quality, background);
            WriteBytes(dzi ? level_dir / (std::to_string(x) + "_" + std::to_string(y) + "." + options.ext)
                           : level_dir / std::to_string(x) / (std::to_string(y) + "." + options.ext),
                       bytes);
            ++done;
          }
        });
        if (progress) progress(double(done) / std::max(1LL, total));
      }
      index.push_back({{"name", name}, {"width", t.image().width()}, {"height", t.image().height()},
                       {"format", options.format}, {"tile_size", 256},
                       {"url", dzi ? name + ".dzi" : name + "/{z}/{x}/{y}." + options.ext},
                       {"max_zoom", dzi ? t.max_level() : t.xyz_max_zoom()},
                       {"dzi_level_of_zoom_0", t.xyz_shift()}});
      if (!dzi) {
        std::ofstream(tmp / (name + ".xml")) << GdalWmsPixel(t, base + "/" + name + "/${z}/${x}/${y}." + options.ext);
        index.back()["gdal_wms"] = name + ".xml";
      }
      if (mercators[i]) {
        const WebMercatorTiles& m = *mercators[i];
        done += WriteWebMercator(m, tmp / name / "webmercator", options.ext, options.jpeg_quality, background,
                                 [&](long long n) {
                                   if (progress) progress(double(done + n) / std::max(1LL, total));
                                 });
        const std::string url = base + "/" + name + "/webmercator/{z}/{x}/{y}." + options.ext;
        std::ofstream(tmp / (name + ".tilejson.json")) << TileJson({name, &m}, url).dump(1) << "\n";
        std::ofstream(tmp / (name + ".webmercator.xml"))
            << GdalWmsWebMercator(m, base + "/" + name + "/webmercator/${z}/${x}/${y}." + options.ext);
        index.back()["webmercator"] = {{"url", name + "/webmercator/{z}/{x}/{y}." + options.ext},
                                       {"tilejson", name + ".tilejson.json"},
                                       {"gdal_wms", name + ".webmercator.xml"},
                                       {"min_zoom", m.min_zoom()},
                                       {"max_zoom", m.max_zoom()},
                                       {"bounds", {m.bounds_wgs84()[0], m.bounds_wgs84()[1], m.bounds_wgs84()[2],
                                                   m.bounds_wgs84()[3]}}};
        layers.push_back({name, &m});
      }
      fs::create_directories(tmp / "overlays");
      std::ofstream(tmp / "overlays" / (name + ".json")) << ImageOverlays(store, name, images[i].second).dump() << "\n";
    }
    if (!layers.empty()) {
      // The capabilities name the tiles by URL only (no KVP GetTile from a static server).
      std::ofstream(tmp / "WMTSCapabilities.xml") << WmtsCapabilities(layers, base);
    }
    std::ofstream(tmp / "images.json") << index.dump(1) << "\n";
    // The viewer page, told that it is static (no server: no export, files instead of the API).
    for (const ViewerAsset& a : ViewerAssets()) {
      std::string text(reinterpret_cast<const char*>(a.data), a.size);
      if (std::string(a.path) == "index.html" || std::string(a.path) == "map.html") {
        const size_t at = text.find("<script");
        text.insert(at, "<script>window.ROLAMOS_STATIC = true;</script>\n");
      }
      fs::create_directories((tmp / a.path).parent_path());
      std::ofstream(tmp / a.path, std::ios::binary) << text;
    }
    result.images = static_cast<int>(images.size());
    result.tiles = done;
    for (const auto& m : mercators)
      if (m)
        for (int z = m->min_zoom(); z <= m->max_zoom(); ++z) result.webmercator_tiles += CountTouching(*m, z);
    result.tiles -= result.webmercator_tiles;
    RenameFile(tmp.string(), dir);
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
  return result;
}

}  // namespace rolamos
