#include <cstdio>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/tile_export.hpp"
#include "util/progress.h"

namespace rolamos::cli {

struct TilesSwitches {
  std::string store, output, background;
  TileExportOptions options;
  bool quiet = false;
};

static int RunTiles(TilesSwitches s) {
  if (!s.background.empty()) {
    if (s.background.size() != 6 || s.background.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos)
      Fail("--background", "\"" + s.background + "\" is not a colour RRGGBB (hex)");
    const long rgb = std::stol(s.background, nullptr, 16);
    s.options.background = {int(rgb & 255), int((rgb >> 8) & 255), int((rgb >> 16) & 255)};
  }
  Progress progress("tiles", s.quiet);
  TileExportResult r = ExportTiles(Store::Open(s.store), s.output, s.options,
                                   [&](double f) { progress.Update(f); });
  progress.Done();
  std::printf("%s: %lld %s tiles of %d images (%s)%s, %.1f s\n", s.output.c_str(), r.tiles,
              s.options.ext.c_str(), r.images, s.options.format.c_str(),
              r.webmercator_tiles > 0 ? (", " + std::to_string(r.webmercator_tiles) + " Web Mercator tiles").c_str() : "",
              progress.ElapsedSeconds());
  return 0;
}

void AddTilesCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<TilesSwitches>();
  auto* cmd = app.add_subcommand("tiles", "Write the tile pyramids of a store for a static web server");
  cmd->add_option("store", s->store, "the store")->required();
  cmd->add_option("-o,--output", s->output, "new directory for the tiles")->required();
  cmd->add_option("--format", s->options.format, "dzi (OpenSeadragon) or xyz (Leaflet/QGIS)")
      ->capture_default_str();
  cmd->add_option("--encoding", s->options.ext, "jpg, png or webp")->capture_default_str();
  cmd->add_option("--jpeg-quality", s->options.jpeg_quality, "JPEG quality")->capture_default_str();
  cmd->add_option("--background", s->background, "xyz JPEG: the colour of \"no data\" (RRGGBB; default 000000)");
  cmd->add_option("--base-url", s->options.base_url,
                  "xyz: the URL the directory will be served from, for TileJSON, WMTSCapabilities.xml and the GDAL "
                  "WMS files (default: file:// URLs of the directory)");
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunTiles(*s); }; });
}

}  // namespace rolamos::cli
