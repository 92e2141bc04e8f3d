#include "rolamos/tile_export.hpp"

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "rolamos/error.hpp"
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
    nlohmann::json index = nlohmann::json::array();
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
        const fs::path level_dir = dzi ? tmp / (name + "_files") / std::to_string(level)
                                       : tmp / name / std::to_string(level - t.xyz_shift());
        for (int x = 0; x < nx && !dzi; ++x) fs::create_directories(level_dir / std::to_string(x));
        if (dzi) fs::create_directories(level_dir);
        cv::parallel_for_(cv::Range(0, nx * ny), [&](const cv::Range& r) {
          for (int k = r.start; k < r.end; ++k) {
            const int x = k % nx, y = k / nx;
            const auto bytes = TilePyramid::Encode(t.Tile(level, x, y), options.ext, options.jpeg_quality);
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
      fs::create_directories(tmp / "overlays");
      std::ofstream(tmp / "overlays" / (name + ".json")) << ImageOverlays(store, name, images[i].second).dump() << "\n";
    }
    std::ofstream(tmp / "images.json") << index.dump(1) << "\n";
    // The viewer page, told that it is static (no server: no export, files instead of the API).
    for (const ViewerAsset& a : ViewerAssets()) {
      std::string text(reinterpret_cast<const char*>(a.data), a.size);
      if (std::string(a.path) == "index.html") {
        const size_t at = text.find("<script");
        text.insert(at, "<script>window.ROLAMOS_STATIC = true;</script>\n");
      }
      std::ofstream(tmp / a.path, std::ios::binary) << text;
    }
    result.images = static_cast<int>(images.size());
    result.tiles = done;
    RenameFile(tmp.string(), dir);
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
  return result;
}

}  // namespace rolamos
