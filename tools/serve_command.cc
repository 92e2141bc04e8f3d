#include <csignal>
#include <cstdio>

#include "command.h"
#include "rolamos/tile_server.hpp"

namespace rolamos::cli {

struct ServeSwitches {
  std::string store;
  TileServerOptions options;
};

static int RunServe(const ServeSwitches& s) {
  // Ctrl-C and SIGTERM are waited for here, not handled in whatever thread they hit.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
  TileServer server(Store::Open(s.store), s.options);
  const int port = server.Start();
  std::printf("serving %s on http://%s:%d/  (open it in a browser: the viewer; images: /api/images; "
              "XYZ: /tiles/NAME/{z}/{x}/{y}.jpg; Deep Zoom: /dzi/NAME.dzi; georeferenced: /map.html, "
              "/wmts/1.0.0/WMTSCapabilities.xml, /tilejson/NAME.json; files: /files/mosaic.tif). Ctrl-C stops.\n",
              s.store.c_str(), s.options.bind.c_str(), port);
  std::fflush(stdout);
  int signal = 0;
  sigwait(&stop_signals, &signal);
  server.Stop();
  std::printf("stopped\n");
  return 0;
}

void AddServeCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<ServeSwitches>();
  auto* cmd = app.add_subcommand("serve", "Serve a store's mosaic and patches as map tiles over HTTP");
  cmd->add_option("store", s->store, "the store")->required();
  cmd->add_option("--port", s->options.port, "port (0: any free one)")->capture_default_str();
  cmd->add_option("--bind", s->options.bind, "address to listen on")->capture_default_str();
  cmd->add_option("--cache-mb", s->options.cache_mb, "tile cache memory")->capture_default_str();
  cmd->add_option("--navigation", s->options.navigation,
                  "a live run's vehicle navigation CSV, read as it grows (compose --navigation's columns): "
                  "georeferences the live view");
  cmd->add_option("--crs", s->options.navigation_crs, "with --navigation: CRS of eastings/northings without an epsg column");
  cmd->add_option("--focal", s->options.focal_px, "with --navigation: focal length in pixels (default: the store's camera)");
  cmd->add_option("--basemap", s->options.basemap,
                  "an XYZ tile URL ({z}/{x}/{y}) the map page (/map.html) shows under the georeferenced mosaic; none "
                  "by default (nothing is fetched from elsewhere unless given)");
  cmd->add_option("--basemap-attribution", s->options.basemap_attribution, "the base map's attribution text");
  cmd->add_option("--basemap-max-zoom", s->options.basemap_max_zoom, "the base map's finest zoom")->capture_default_str();
  cmd->add_option("--threads", s->options.threads, "request threads (0: 4 per core, at least 16)")
      ->capture_default_str();
  cmd->callback([s, run] { *run = [s] { return RunServe(*s); }; });
}

}  // namespace rolamos::cli
