// Georef's arithmetic, apart from its reading and writing (georef_io.cc): the TIFF writer checks a
// georeference without GDAL, which a mosaic run does not load (tools/main.cc).
#include <cmath>

#include "rolamos/georef_io.hpp"

namespace rolamos {

bool Georef::IsValid(std::string* error) const {
  for (double v : geotransform) {
    if (!std::isfinite(v)) {
      *error = "geotransform has a non-finite number";
      return false;
    }
  }
  const double det = geotransform[1] * geotransform[5] - geotransform[2] * geotransform[4];
  if (det == 0.0) {
    *error = "geotransform is degenerate (pixel size zero)";
    return false;
  }
  if (crs.empty()) {
    *error = "CRS is empty";
    return false;
  }
  return true;
}

Georef Georef::ForWindow(double x, double y, double scale) const {
  Georef g = *this;
  const auto& t = geotransform;
  g.geotransform[0] = t[0] + x * t[1] + y * t[2];
  g.geotransform[3] = t[3] + x * t[4] + y * t[5];
  g.geotransform[1] = t[1] / scale;
  g.geotransform[2] = t[2] / scale;
  g.geotransform[4] = t[4] / scale;
  g.geotransform[5] = t[5] / scale;
  return g;
}

std::array<double, 2> Georef::PixelToMap(double x, double y) const {
  const auto& t = geotransform;
  return {t[0] + x * t[1] + y * t[2], t[3] + x * t[4] + y * t[5]};
}

}  // namespace rolamos
