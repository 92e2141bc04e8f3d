// `mosaic --live --serve`: the viewer served while mapping. In its own file, in the full module
// only, because the tile server brings GDAL and OpenImageIO, which the launcher is linked without
// (main.cc): the launcher's `mosaic` starts it through the module (rolamos_start_live_viewer).
#include <cstdio>

#include "command.h"
#include "rolamos/tile_server.hpp"

namespace rolamos::cli {

std::shared_ptr<void> StartLiveViewer(Store& store, const LiveViewerSwitches& v) {
  TileServerOptions so;
  so.port = v.port;
  so.bind = v.bind;
  so.live = true;
  so.navigation = v.navigation;
  so.navigation_crs = v.navigation_crs;
  so.focal_px = v.focal_px;
  auto server = std::make_shared<TileServer>(store, so);
  const int port = server->Start();
  std::printf("viewer on http://%s:%d/ while the run lasts (rolamos serve %s serves it after)\n", v.bind.c_str(), port,
              store.dir().c_str());
  std::fflush(stdout);
  return server;  // released: its destructor stops it
}

}  // namespace rolamos::cli

// For the launcher (dlsym): C linkage, the result through a pointer.
extern "C" void rolamos_start_live_viewer(rolamos::Store* store, const rolamos::cli::LiveViewerSwitches* viewer,
                                          std::shared_ptr<void>* handle) {
  *handle = rolamos::cli::StartLiveViewer(*store, *viewer);
}
