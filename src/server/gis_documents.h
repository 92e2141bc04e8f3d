// What GIS clients read to add a survey by URL: TileJSON 3.0.0 (web maps), an OGC WMTS 1.0.0
// capabilities document (QGIS, GDAL's WMTS driver, OpenLayers) over the Web Mercator tiles, and
// GDAL WMS service descriptions of the XYZ tiles (GDAL's TMS minidriver; QGIS opens them too).
// Served by `rolamos serve` and written by `rolamos tiles`.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "server/tile_pyramid.h"
#include "server/web_mercator.h"

namespace rolamos {

// A georeferenced image as the documents name it.
struct GisLayer {
  std::string name;               // "mosaic", "patch-N"
  const WebMercatorTiles* tiles;  // its Web Mercator grid
};

// TileJSON of the image's Web Mercator tiles at `tiles_url` ("{z}/{x}/{y}" placeholders).
nlohmann::json TileJson(const GisLayer& layer, const std::string& tiles_url);

// WMTS capabilities: every layer in the GoogleMapsCompatible tile matrix set, tiles at
// `base_url`/tiles/NAME/webmercator/{TileMatrix}/{TileCol}/{TileRow}.{png,jpg}, GetTile by KVP at
// `base_url`/wmts.
std::string WmtsCapabilities(const std::vector<GisLayer>& layers, const std::string& base_url);

// An OGC exception report (WMTS's way of saying what was wrong with a request).
std::string OgcException(const std::string& code, const std::string& locator, const std::string& text);

// GDAL WMS (TMS minidriver) description of the pixel XYZ tiles at `tiles_url` (${z}/${x}/${y})
// at zoom `zoom` (< 0: full resolution): a raster of the whole tiles that cover the image (the
// part past it transparent), in pixel coordinates (x = column, y = -row of full resolution).
std::string GdalWmsPixel(const TilePyramid& pyramid, const std::string& tiles_url, int zoom = -1);
// The same for the Web Mercator tiles (EPSG:3857): the tiles of zoom `zoom` (< 0: the map's full
// resolution) that cover the map, placed in the world's grid (GDAL's TileX/TileY: any zoom fits
// GDAL's raster size limit, where the whole world at zoom 23 and finer would not).
std::string GdalWmsWebMercator(const WebMercatorTiles& tiles, const std::string& tiles_url, int zoom = -1);

}  // namespace rolamos
