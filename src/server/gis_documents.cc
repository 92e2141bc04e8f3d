#include "server/gis_documents.h"

#include <cmath>
#include <cstdio>
#include <set>

namespace rolamos {

namespace {

std::string Num(double v, int digits = 12) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*g", digits, v);
  return b;
}

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '&') out += "&amp;";
    else if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '"') out += "&quot;";
    else out += c;
  }
  return out;
}

// Well-known scale set GoogleMapsCompatible: zoom 0 is one 256-pixel tile for the world, at
// OGC's standard 0.28 mm pixel.
constexpr double kScaleZero = 559082264.0287178;

std::string MatrixSetName(int max_zoom) { return "GoogleMapsCompatible_" + std::to_string(max_zoom); }

}  // namespace

nlohmann::json TileJson(const GisLayer& layer, const std::string& tiles_url) {
  const auto& b = layer.tiles->bounds_wgs84();
  const int centre_zoom = std::max(layer.tiles->min_zoom(), std::min(layer.tiles->max_zoom(), layer.tiles->min_zoom() + 2));
  return {{"tilejson", "3.0.0"},
          {"name", layer.name},
          {"description", "rolamos seafloor map " + layer.name + " (Web Mercator tiles, no data transparent)"},
          {"scheme", "xyz"},
          {"tiles", {tiles_url}},
          {"minzoom", layer.tiles->min_zoom()},
          {"maxzoom", layer.tiles->max_zoom()},
          {"bounds", {b[0], b[1], b[2], b[3]}},
          {"center", {0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3]), centre_zoom}}};
}

std::string WmtsCapabilities(const std::vector<GisLayer>& layers, const std::string& base_url) {
  std::string x;
  x += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  x += "<Capabilities xmlns=\"http://www.opengis.net/wmts/1.0\" xmlns:ows=\"http://www.opengis.net/ows/1.1\" "
       "xmlns:xlink=\"http://www.w3.org/1999/xlink\" xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" "
       "xmlns:gml=\"http://www.opengis.net/gml\" xsi:schemaLocation=\"http://www.opengis.net/wmts/1.0 "
       "http://schemas.opengis.net/wmts/1.0/wmtsGetCapabilities_response.xsd\" version=\"1.0.0\">\n";
  x += "  <ows:ServiceIdentification>\n    <ows:Title>rolamos seafloor maps</ows:Title>\n"
       "    <ows:ServiceType>OGC WMTS</ows:ServiceType>\n    <ows:ServiceTypeVersion>1.0.0</ows:ServiceTypeVersion>\n"
       "  </ows:ServiceIdentification>\n";
  x += "  <ows:OperationsMetadata>\n";
  for (const char* op : {"GetCapabilities", "GetTile"}) {
    x += std::string("    <ows:Operation name=\"") + op + "\">\n      <ows:DCP><ows:HTTP><ows:Get xlink:href=\"" +
         Escape(base_url) + "/wmts?\"><ows:Constraint name=\"GetEncoding\"><ows:AllowedValues><ows:Value>KVP"
         "</ows:Value></ows:AllowedValues></ows:Constraint></ows:Get></ows:HTTP></ows:DCP>\n    </ows:Operation>\n";
  }
  x += "  </ows:OperationsMetadata>\n  <Contents>\n";
  std::set<int> sets;
  for (const GisLayer& l : layers) {
    const auto& b = l.tiles->bounds_wgs84();
    sets.insert(l.tiles->max_zoom());
    x += "    <Layer>\n      <ows:Title>" + Escape(l.name) + "</ows:Title>\n";
    x += "      <ows:WGS84BoundingBox>\n        <ows:LowerCorner>" + Num(b[0]) + " " + Num(b[1]) +
         "</ows:LowerCorner>\n        <ows:UpperCorner>" + Num(b[2]) + " " + Num(b[3]) +
         "</ows:UpperCorner>\n      </ows:WGS84BoundingBox>\n";
    x += "      <ows:Identifier>" + Escape(l.name) + "</ows:Identifier>\n";
    x += "      <Style isDefault=\"true\"><ows:Identifier>default</ows:Identifier></Style>\n";
    x += "      <Format>image/png</Format>\n      <Format>image/jpeg</Format>\n";
    x += "      <TileMatrixSetLink><TileMatrixSet>" + MatrixSetName(l.tiles->max_zoom()) + "</TileMatrixSet></TileMatrixSetLink>\n";
    for (const auto& [format, ext] : {std::pair<const char*, const char*>("image/png", "png"), {"image/jpeg", "jpg"}})
      x += std::string("      <ResourceURL format=\"") + format + "\" resourceType=\"tile\" template=\"" + Escape(base_url) +
           "/tiles/" + Escape(l.name) + "/webmercator/{TileMatrix}/{TileCol}/{TileRow}." + ext + "\"/>\n";
    x += "    </Layer>\n";
  }
  for (int max_zoom : sets) {
    x += "    <TileMatrixSet>\n      <ows:Identifier>" + MatrixSetName(max_zoom) + "</ows:Identifier>\n";
    x += "      <ows:SupportedCRS>urn:ogc:def:crs:EPSG::3857</ows:SupportedCRS>\n";
    x += "      <WellKnownScaleSet>urn:ogc:def:wkss:OGC:1.0:GoogleMapsCompatible</WellKnownScaleSet>\n";
    for (int z = 0; z <= max_zoom; ++z) {
      const long long n = 1LL << z;
      x += "      <TileMatrix><ows:Identifier>" + std::to_string(z) + "</ows:Identifier><ScaleDenominator>" +
           Num(kScaleZero / double(n), 17) + "</ScaleDenominator><TopLeftCorner>-20037508.3427892 20037508.3427892"
           "</TopLeftCorner><TileWidth>256</TileWidth><TileHeight>256</TileHeight><MatrixWidth>" + std::to_string(n) +
           "</MatrixWidth><MatrixHeight>" + std::to_string(n) + "</MatrixHeight></TileMatrix>\n";
    }
    x += "    </TileMatrixSet>\n";
  }
  x += "  </Contents>\n</Capabilities>\n";
  return x;
}

std::string OgcException(const std::string& code, const std::string& locator, const std::string& text) {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<ows:ExceptionReport xmlns:ows=\"http://www.opengis.net/ows/1.1\" "
         "version=\"2.0.0\">\n  <ows:Exception exceptionCode=\"" + Escape(code) + "\" locator=\"" + Escape(locator) +
         "\">\n    <ows:ExceptionText>" + Escape(text) + "</ows:ExceptionText>\n  </ows:Exception>\n"
         "</ows:ExceptionReport>\n";
}

namespace {

// A GDAL WMS TMS description of a window of whole tiles: tiles [tx0, tx0 + nx) x [ty0, ty0 + ny)
// of zoom `zoom`, tile (tx0, ty0)'s corner at (ulx, uly), `tile_units` map units a tile.
std::string GdalWms(const std::string& tiles_url, int zoom, long long tx0, long long ty0, long long nx, long long ny,
                    double ulx, double uly, double tile_units, const std::string& projection) {
  return "<GDAL_WMS>\n  <Service name=\"TMS\"><ServerUrl>" + Escape(tiles_url) + "</ServerUrl></Service>\n"
         "  <DataWindow><UpperLeftX>" + Num(ulx, 17) + "</UpperLeftX><UpperLeftY>" + Num(uly, 17) +
         "</UpperLeftY><LowerRightX>" + Num(ulx + nx * tile_units, 17) + "</LowerRightX><LowerRightY>" +
         Num(uly - ny * tile_units, 17) + "</LowerRightY><SizeX>" + std::to_string(nx * 256) + "</SizeX><SizeY>" +
         std::to_string(ny * 256) + "</SizeY><TileX>" + std::to_string(tx0) + "</TileX><TileY>" + std::to_string(ty0) +
         "</TileY><TileLevel>" + std::to_string(zoom) + "</TileLevel><YOrigin>top</YOrigin></DataWindow>\n" +
         (projection.empty() ? "" : "  <Projection>" + projection + "</Projection>\n") +
         "  <BlockSizeX>256</BlockSizeX><BlockSizeY>256</BlockSizeY><BandsCount>4</BandsCount>\n"
         "  <ZeroBlockHttpCodes>204,404</ZeroBlockHttpCodes>\n</GDAL_WMS>\n";
}

}  // namespace

std::string GdalWmsPixel(const TilePyramid& pyramid, const std::string& tiles_url, int zoom) {
  const int z = zoom < 0 ? pyramid.xyz_max_zoom() : std::min(zoom, pyramid.xyz_max_zoom());
  const cv::Size size = pyramid.LevelSize(z + pyramid.xyz_shift());
  const double tile_units = 256.0 * std::ldexp(1.0, pyramid.xyz_max_zoom() - z);  // full-resolution pixels
  return GdalWms(tiles_url, z, 0, 0, (size.width + 255) / 256, (size.height + 255) / 256, 0, 0, tile_units, "");
}

std::string GdalWmsWebMercator(const WebMercatorTiles& tiles, const std::string& tiles_url, int zoom) {
  const int z = zoom < 0 ? tiles.max_zoom() : std::min(zoom, tiles.max_zoom());
  const double tile_units = 2 * WebMercatorTiles::kHalfWorld / std::ldexp(1.0, z);
  const auto& b = tiles.bounds_3857();
  const long long tx0 = static_cast<long long>(std::floor((b[0] + WebMercatorTiles::kHalfWorld) / tile_units));
  const long long tx1 = static_cast<long long>(std::floor((b[2] + WebMercatorTiles::kHalfWorld) / tile_units));
  const long long ty0 = static_cast<long long>(std::floor((WebMercatorTiles::kHalfWorld - b[3]) / tile_units));
  const long long ty1 = static_cast<long long>(std::floor((WebMercatorTiles::kHalfWorld - b[1]) / tile_units));
  return GdalWms(tiles_url, z, tx0, ty0, tx1 - tx0 + 1, ty1 - ty0 + 1, -WebMercatorTiles::kHalfWorld + tx0 * tile_units,
                 WebMercatorTiles::kHalfWorld - ty0 * tile_units, tile_units, "EPSG:3857");
}

}  // namespace rolamos
