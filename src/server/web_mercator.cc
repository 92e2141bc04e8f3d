#include "server/web_mercator.h"

#include <gdal_priv.h>
#include <gdal_utils.h>
#include <ogr_spatialref.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "raster/gdal_setup.h"
#include "rolamos/error.hpp"

namespace rolamos {

namespace {

constexpr double kEarthRadius = 6378137.0;  // Web Mercator's sphere, metres

double ToLon(double x) { return x / kEarthRadius * 180.0 / CV_PI; }
double ToLat(double y) { return std::atan(std::sinh(y / kEarthRadius)) * 180.0 / CV_PI; }

std::string Number(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.10g", v);
  return b;
}

}  // namespace

std::unique_ptr<WebMercatorTiles> WebMercatorTiles::Open(const std::string& path, std::string* why) {
  EnsureGdal();
  TakeGdalError();
  GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  if (!ds) Fail(path, "GDAL cannot open it: " + TakeGdalError());
  double g[6];
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  if (ds->GetGeoTransform(g) != CE_None || !srs || srs->IsEmpty()) {
    *why = "the map is not georeferenced (compose --navigation places it on Earth)";
    return nullptr;
  }
  if (srs->IsLocal() || !(srs->IsProjected() || srs->IsGeographic())) {
    *why = "the map is in a local frame, not on Earth (compose --navigation places it there)";
    return nullptr;
  }
  OGRSpatialReference source(*srs), mercator;
  source.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  mercator.importFromEPSG(3857);
  mercator.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> to_merc(OGRCreateCoordinateTransformation(&source, &mercator));
  if (!to_merc) {
    *why = "its CRS cannot be transformed to Web Mercator: " + TakeGdalError();
    return nullptr;
  }
  const double w = ds->GetRasterXSize(), h = ds->GetRasterYSize();
  // The map's outline, 16 points a side, and the size of a pixel at its centre.
  std::vector<double> xs, ys;
  for (int i = 0; i <= 16; ++i) {
    const double t = i / 16.0;
    for (const auto& [c, r] : {std::pair<double, double>(t * w, 0), {t * w, h}, {0, t * h}, {w, t * h}}) {
      xs.push_back(g[0] + c * g[1] + r * g[2]);
      ys.push_back(g[3] + c * g[4] + r * g[5]);
    }
  }
  const size_t border = xs.size();
  for (const auto& [c, r] : {std::pair<double, double>(w / 2, h / 2), {w / 2 + 1, h / 2}, {w / 2, h / 2 + 1}}) {
    xs.push_back(g[0] + c * g[1] + r * g[2]);
    ys.push_back(g[3] + c * g[4] + r * g[5]);
  }
  if (!to_merc->Transform(static_cast<int>(xs.size()), xs.data(), ys.data())) {
    *why = "its corners cannot be placed in Web Mercator";
    return nullptr;
  }
  auto out = std::unique_ptr<WebMercatorTiles>(new WebMercatorTiles());
  out->path_ = path;
  out->bounds_ = {*std::min_element(xs.begin(), xs.begin() + long(border)),
                  *std::min_element(ys.begin(), ys.begin() + long(border)),
                  *std::max_element(xs.begin(), xs.begin() + long(border)),
                  *std::max_element(ys.begin(), ys.begin() + long(border))};
  out->lonlat_ = {ToLon(out->bounds_[0]), ToLat(out->bounds_[1]), ToLon(out->bounds_[2]), ToLat(out->bounds_[3])};
  const double res = 0.5 * (std::hypot(xs[border + 1] - xs[border], ys[border + 1] - ys[border]) +
                            std::hypot(xs[border + 2] - xs[border], ys[border + 2] - ys[border]));
  const double world = 2 * kHalfWorld;
  out->max_zoom_ = std::clamp(static_cast<int>(std::ceil(std::log2(world / kTile / std::max(res, 1e-9)))), 0, 30);
  const double extent = std::max(out->bounds_[2] - out->bounds_[0], out->bounds_[3] - out->bounds_[1]);
  out->min_zoom_ = std::clamp(static_cast<int>(std::floor(std::log2(world / std::max(extent, 1e-9)))), 0,
                              out->max_zoom_);
  return out;
}

std::array<double, 4> WebMercatorTiles::TileBounds(int z, long long x, long long y) {
  const double size = 2 * kHalfWorld / std::ldexp(1.0, z);
  return {-kHalfWorld + x * size, kHalfWorld - (y + 1) * size, -kHalfWorld + (x + 1) * size, kHalfWorld - y * size};
}

bool WebMercatorTiles::InGrid(int z, long long x, long long y) const {
  return z >= 0 && z <= 30 && x >= 0 && y >= 0 && x < (1LL << z) && y < (1LL << z);
}

bool WebMercatorTiles::Touches(int z, long long x, long long y) const {
  if (!InGrid(z, x, y)) return false;
  const auto b = TileBounds(z, x, y);
  return b[0] < bounds_[2] && b[2] > bounds_[0] && b[1] < bounds_[3] && b[3] > bounds_[1];
}

cv::Mat WebMercatorTiles::Tile(int z, long long x, long long y) const {
  if (!InGrid(z, x, y)) return {};
  cv::Mat out(kTile, kTile, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  if (!Touches(z, x, y)) return out;
  EnsureGdal();
  TakeGdalError();
  GDALDatasetH source = GDALOpenEx(path_.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, nullptr, nullptr, nullptr);
  if (!source) Fail(path_, "GDAL cannot open it: " + TakeGdalError());
  const auto b = TileBounds(z, x, y);
  const int bands = GDALGetRasterCount(source);
  const bool alpha = GDALGetRasterColorInterpretation(GDALGetRasterBand(source, bands)) == GCI_AlphaBand;
  CPLStringList args;
  for (const std::string a : {"-of", "MEM", "-t_srs", "EPSG:3857", "-r", "bilinear", "-ovr", "AUTO", "-q"})
    args.AddString(a.c_str());
  args.AddString("-te");
  for (double v : b) args.AddString(Number(v).c_str());
  args.AddString("-ts");
  args.AddString(std::to_string(kTile).c_str());
  args.AddString(std::to_string(kTile).c_str());
  if (!alpha) args.AddString("-dstalpha");
  GDALWarpAppOptions* options = GDALWarpAppOptionsNew(args.List(), nullptr);
  int usage_error = 0;
  GDALDatasetH warped = GDALWarp("", nullptr, 1, &source, options, &usage_error);
  GDALWarpAppOptionsFree(options);
  if (!warped) {
    GDALClose(source);
    Fail(path_, "GDAL could not warp Web Mercator tile " + std::to_string(z) + "/" + std::to_string(x) + "/" +
                    std::to_string(y) + ": " + TakeGdalError());
  }
  // Colour (1 gray or 3 RGB bands) and the alpha band GDAL carried or made, into BGRA.
  const int n = GDALGetRasterCount(warped);
  const bool deep = GDALGetRasterDataType(GDALGetRasterBand(warped, 1)) != GDT_Byte;
  std::vector<cv::Mat> planes;
  CPLErr err = CE_None;
  for (int k = 1; k <= n && err == CE_None; ++k) {
    cv::Mat plane(kTile, kTile, deep ? CV_16U : CV_8U);
    err = GDALRasterIO(GDALGetRasterBand(warped, k), GF_Read, 0, 0, kTile, kTile, plane.data, kTile, kTile,
                       deep ? GDT_UInt16 : GDT_Byte, 0, 0);
    if (deep) plane.convertTo(plane, CV_8U, 1.0 / 257.0);
    planes.push_back(plane);
  }
  GDALClose(warped);
  GDALClose(source);
  if (err != CE_None || n < 2) Fail(path_, "GDAL could not read a warped tile: " + TakeGdalError());
  const cv::Mat& a = planes.back();
  const cv::Mat bgra[4] = {n >= 4 ? planes[2] : planes[0], n >= 4 ? planes[1] : planes[0], planes[0], a};
  cv::merge(bgra, 4, out);
  return out;
}

}  // namespace rolamos
