// Georeference of a raster: a CRS and a GDAL-style affine geotransform
// (x_map = gt[0] + col*gt[1] + row*gt[2]; y_map = gt[3] + col*gt[4] + row*gt[5]).
#pragma once

#include <array>
#include <optional>
#include <string>

namespace rolamos {

struct Georef {
  std::string crs;  // anything GDAL's SetFromUserInput takes (EPSG:32755, WKT, PROJ); stored as WKT
  std::array<double, 6> geotransform{0, 1, 0, 0, 0, 1};

  bool IsValid(std::string* error) const;
  // The same georeference for a window starting at (x, y) of this raster, resampled by `scale`
  // (output pixel = scale * input pixel).
  Georef ForWindow(double x, double y, double scale) const;
  // Map coordinates of a pixel position.
  std::array<double, 2> PixelToMap(double x, double y) const;
};

// Normalises a user CRS string to WKT; throws Error naming the string when GDAL cannot parse it.
std::string CrsToWkt(const std::string& user_crs);

// "EPSG::32755" style authority and code of a CRS (for GeoJSON's "crs" member), or "" when
// GDAL knows none.
std::string CrsAuthorityCode(const std::string& crs);

// Writes GeoTIFF tags into an existing TIFF (through GDAL, in place).
void WriteGeoref(const std::string& tiff_path, const Georef& georef);

// Reads the georeference GDAL sees in any raster; nullopt when there is none.
std::optional<Georef> ReadGeoref(const std::string& path);

}  // namespace rolamos
