#include "rolamos/georef_io.hpp"

#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include <cmath>

#include "rolamos/error.hpp"
#include "raster/gdal_setup.h"

namespace rolamos {

std::string CrsToWkt(const std::string& user_crs) {
  EnsureGdal();
  TakeGdalError();
  OGRSpatialReference srs;
  if (user_crs.empty() || srs.SetFromUserInput(user_crs.c_str()) != OGRERR_NONE)
    Fail("CRS '" + user_crs.substr(0, 200) + "'", "GDAL cannot parse it (" + TakeGdalError() + ")");
  char* wkt = nullptr;
  const char* options[] = {"FORMAT=WKT2_2019", nullptr};
  srs.exportToWkt(&wkt, options);
  std::string out = wkt ? wkt : "";
  CPLFree(wkt);
  return out;
}

std::string CrsAuthorityCode(const std::string& crs) {
  EnsureGdal();
  TakeGdalError();
  OGRSpatialReference srs;
  if (crs.empty() || srs.SetFromUserInput(crs.c_str()) != OGRERR_NONE) {
    TakeGdalError();
    return "";
  }
  srs.AutoIdentifyEPSG();
  const char* name = srs.GetAuthorityName(nullptr);
  const char* code = srs.GetAuthorityCode(nullptr);
  TakeGdalError();
  return name && code ? std::string(name) + "::" + code : "";
}

void WriteGeoref(const std::string& tiff_path, const Georef& georef) {
  std::string error;
  if (!georef.IsValid(&error)) Fail(tiff_path, "georeference: " + error);
  const std::string wkt = CrsToWkt(georef.crs);
  EnsureGdal();
  TakeGdalError();  // only errors of this call count below
  GDALDatasetUniquePtr ds(GDALDataset::Open(tiff_path.c_str(), GDAL_OF_RASTER | GDAL_OF_UPDATE));
  if (!ds) Fail(tiff_path, "GDAL cannot open it to write the georeference: " + TakeGdalError());
  double gt[6];
  std::copy(georef.geotransform.begin(), georef.geotransform.end(), gt);
  if (ds->SetGeoTransform(gt) != CE_None || ds->SetProjection(wkt.c_str()) != CE_None)
    Fail(tiff_path, "cannot write the georeference: " + TakeGdalError());
  ds.reset();  // flushes the GeoTIFF tags
  const std::string late = TakeGdalError();
  if (!late.empty()) Fail(tiff_path, "writing the georeference: " + late);
}

std::optional<Georef> ReadGeoref(const std::string& path) {
  EnsureGdal();
  GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  // Whatever GDAL complained about while probing is not this caller's error: leave none behind.
  TakeGdalError();
  if (!ds) return std::nullopt;
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  double gt[6];
  if (!srs || srs->IsEmpty() || ds->GetGeoTransform(gt) != CE_None) return std::nullopt;
  char* wkt = nullptr;
  const char* options[] = {"FORMAT=WKT2_2019", nullptr};
  srs->exportToWkt(&wkt, options);
  Georef g;
  g.crs = wkt ? wkt : "";
  CPLFree(wkt);
  std::copy(gt, gt + 6, g.geotransform.begin());
  return g;
}

}  // namespace rolamos
