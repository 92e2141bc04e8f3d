// `mosaic --live --serve`: the viewer served while mapping. In its own file because the tile
// server brings GDAL and OpenImageIO, which the launcher's own `mosaic` is linked without
// (main.cc): the launcher hands a run with --serve to the full module.
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
