#include <cstdio>

#include "command.h"
#include "rolamos/tile_export.hpp"
#include "util/progress.h"

namespace rolamos::cli {

struct TilesSwitches {
  std::string store, output;
  TileExportOptions options;
  bool quiet = false;
};

static int RunTiles(const TilesSwitches& s) {
  Progress progress("tiles", s.quiet);
  TileExportResult r = ExportTiles(Store::Open(s.store), s.output, s.options,
                                   [&](double f) { progress.Update(f); });
  progress.Done();
  std::printf("%s: %lld %s tiles of %d images (%s), %.1f s\n", s.output.c_str(), r.tiles,
              s.options.ext.c_str(), r.images, s.options.format.c_str(), progress.ElapsedSeconds());
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
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunTiles(*s); }; });
}

}  // namespace rolamos::cli
