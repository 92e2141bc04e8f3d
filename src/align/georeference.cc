#include "rolamos/georeference.hpp"

#include "align/navigation_fit.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include <ogr_spatialref.h>
#include <opencv2/calib3d.hpp>

#include "rolamos/error.hpp"
#include "store/writer_lock.h"
#include "util/files.h"
#include "util/homography.h"

namespace fs = std::filesystem;

namespace rolamos {

namespace {

std::vector<std::string> SplitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, ',')) {
    while (!cell.empty() && (cell.back() == '\r' || cell.back() == ' ')) cell.pop_back();
    out.push_back(cell);
  }
  return out;
}


}  // namespace

std::map<std::string, FrameNavigation> ReadFrameNavigationCsv(const std::string& path,
                                                              std::vector<std::string>* skipped) {
  std::ifstream in(path);
  if (!in) Fail(path, "cannot be read");
  std::string line;
  if (!std::getline(in, line)) Fail(path, "is empty");
  const auto header = SplitCsv(line);
  int frame = -1, epsg = -1, sequence = -1, gt[6] = {-1, -1, -1, -1, -1, -1};
  for (int i = 0; i < static_cast<int>(header.size()); ++i) {
    const std::string h = ToLower(header[static_cast<size_t>(i)]);
    if (h == "frame") frame = i;
    if (h == "epsg") epsg = i;
    if (h == "sequence") sequence = i;
    for (int k = 0; k < 6; ++k)
      if (h == "gt" + std::to_string(k) || h.rfind("gt" + std::to_string(k) + "_", 0) == 0) gt[k] = i;
  }
  if (frame < 0 || epsg < 0 || *std::min_element(gt, gt + 6) < 0)
    Fail(path, "needs the columns frame, epsg and gt0..gt5");
  std::map<std::string, FrameNavigation> nav;
  int number = 1;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty()) continue;
    if (skipped && in.eof()) break;  // a growing file's last line, perhaps half written
    const std::string where = path + ":" + std::to_string(number);
    try {
      const auto cells = SplitCsv(line);
      if (cells.size() < header.size()) Fail(where, "has " + std::to_string(cells.size()) + " columns, the header " +
                                                        std::to_string(header.size()));
      FrameNavigation f;
      f.crs = "EPSG:" + cells[static_cast<size_t>(epsg)];
      for (int k = 0; k < 6; ++k) {
        try {
          size_t used = 0;
          f.geotransform[static_cast<size_t>(k)] = std::stod(cells[static_cast<size_t>(gt[k])], &used);
          if (used != cells[static_cast<size_t>(gt[k])].size()) throw std::invalid_argument("");
        } catch (const std::exception&) {
          Fail(where, "column " + header[static_cast<size_t>(gt[k])] + " is not a number");
        }
        if (!std::isfinite(f.geotransform[static_cast<size_t>(k)]))
          Fail(where, "column " + header[static_cast<size_t>(gt[k])] + " is not finite");
      }
      const std::string key = (sequence >= 0 ? cells[static_cast<size_t>(sequence)] + "/" : "") +
                              cells[static_cast<size_t>(frame)];
      nav[key] = f;
    } catch (const Error& e) {
      if (!skipped) throw;
      skipped->push_back(e.what());
    }
  }
  if (nav.empty() && !skipped) Fail(path, "lists no frames");
  return nav;
}

bool NavigationCamera::IsValid(std::string* error) const {
  if (!(focal_px > 0) || !std::isfinite(focal_px)) {
    *error = "the camera's focal length in pixels is needed to turn positions into footprints";
    return false;
  }
  if ((cx < 0 || cy < 0) && (width <= 0 || height <= 0)) {
    *error = "the principal point or the frame size is needed";
    return false;
  }
  return true;
}

namespace {

// WGS 84 lat/lon -> UTM of the zone of (lat0, lon0), through GDAL.
class ToUtm {
 public:
  ToUtm(double lat0, double lon0) {
    const int zone = std::clamp(static_cast<int>(std::floor((lon0 + 180) / 6)) + 1, 1, 60);
    epsg_ = (lat0 >= 0 ? 32600 : 32700) + zone;
    OGRSpatialReference wgs84, utm;
    wgs84.importFromEPSG(4326);
    wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    utm.importFromEPSG(epsg_);
    utm.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    transform_.reset(OGRCreateCoordinateTransformation(&wgs84, &utm));
    if (!transform_) Fail("EPSG:" + std::to_string(epsg_), "GDAL cannot transform WGS 84 into it");
  }
  cv::Point2d operator()(double lat, double lon) const {
    double x = lon, y = lat;
    if (!transform_->Transform(1, &x, &y)) Fail("lat/lon " + std::to_string(lat) + "," + std::to_string(lon), "cannot be transformed");
    return {x, y};
  }
  int epsg() const { return epsg_; }

 private:
  int epsg_ = 0;
  std::unique_ptr<OGRCoordinateTransformation> transform_;
};

}  // namespace

std::map<std::string, FrameNavigation> ReadVehicleNavigationCsv(const std::string& path,
                                                                const NavigationCamera& camera,
                                                                const std::string& crs,
                                                                std::vector<std::string>* skipped) {
  std::string error;
  if (!camera.IsValid(&error)) Fail(path, error);
  std::ifstream in(path);
  if (!in) Fail(path, "cannot be read");
  std::string line;
  if (!std::getline(in, line)) Fail(path, "is empty");
  const auto header = SplitCsv(line);
  std::map<std::string, int> col;
  for (int i = 0; i < static_cast<int>(header.size()); ++i) col[ToLower(header[static_cast<size_t>(i)])] = i;
  auto find = [&](std::initializer_list<const char*> names) {
    for (const char* n : names)
      if (col.count(n)) return col[n];
    return -1;
  };
  const int frame = find({"frame", "file", "image"});
  const int e = find({"easting", "x", "e"}), n = find({"northing", "y", "n"});
  const int lat = find({"lat", "latitude"}), lon = find({"lon", "longitude", "lng"});
  const int alt = find({"altitude", "alt", "altitude_m"}), heading = find({"heading", "yaw", "heading_deg"});
  const int epsg = find({"epsg"});
  if (frame < 0 || alt < 0 || heading < 0 || ((e < 0 || n < 0) && (lat < 0 || lon < 0)))
    Fail(path, "needs the columns frame, easting,northing (or lat,lon), altitude and heading");
  const bool geographic = e < 0 || n < 0;
  if (!geographic && epsg < 0 && crs.empty())
    Fail(path, "gives eastings and northings without an epsg column: their CRS must be given (EPSG:XXXX)");
  const double cx = camera.cx >= 0 ? camera.cx : (camera.width - 1) / 2.0;
  const double cy = camera.cy >= 0 ? camera.cy : (camera.height - 1) / 2.0;
  std::unique_ptr<ToUtm> to_utm;
  std::map<std::string, FrameNavigation> nav;
  int number = 1;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty() || line == "\r") continue;
    if (skipped && in.eof()) break;  // a growing file's last line, perhaps half written
    const std::string where = path + ":" + std::to_string(number);
    try {
      const auto cells = SplitCsv(line);
      if (cells.size() < header.size()) Fail(where, "has fewer columns than the header");
      auto number_at = [&](int c) {
        try {
          size_t used = 0;
          const double v = std::stod(cells[static_cast<size_t>(c)], &used);
          if (used != cells[static_cast<size_t>(c)].size() || !std::isfinite(v)) throw std::invalid_argument("");
          return v;
        } catch (const std::exception&) {
          Fail(where, "column " + header[static_cast<size_t>(c)] + " is not a number");
        }
      };
      cv::Point2d position;
      FrameNavigation f;
      if (geographic) {
        const double la = number_at(lat), lo = number_at(lon);
        if (std::abs(la) > 90 || std::abs(lo) > 180) Fail(where, "latitude/longitude out of range");
        if (!to_utm) to_utm = std::make_unique<ToUtm>(la, lo);
        position = (*to_utm)(la, lo);
        f.crs = "EPSG:" + std::to_string(to_utm->epsg());
      } else {
        position = {number_at(e), number_at(n)};
        f.crs = epsg >= 0 ? "EPSG:" + cells[static_cast<size_t>(epsg)] : crs;
      }
      const double altitude = number_at(alt);
      if (!(altitude > 0)) Fail(where, "altitude must be positive (metres above the seabed)");
      const double psi = number_at(heading) * CV_PI / 180.0, gsd = altitude / camera.focal_px;
      // Nadir camera, image top towards the heading: right = (cos, -sin), down = (-sin, -cos) in (E, N).
      const double g1 = gsd * std::cos(psi), g2 = -gsd * std::sin(psi);
      const double g4 = -gsd * std::sin(psi), g5 = -gsd * std::cos(psi);
      f.geotransform = {position.x - g1 * cx - g2 * cy, g1, g2, position.y - g4 * cx - g5 * cy, g4, g5};
      std::string key = cells[static_cast<size_t>(frame)];
      nav[key] = f;
    } catch (const Error& e) {
      if (!skipped) throw;
      skipped->push_back(e.what());
    }
  }
  if (nav.empty() && !skipped) Fail(path, "lists no frames");
  return nav;
}

std::map<std::string, FrameNavigation> ReadNavigationCsv(const std::string& path, const NavigationCamera& camera,
                                                         const std::string& crs, std::vector<std::string>* skipped) {
  std::ifstream in(path);
  std::string line;
  if (!in || !std::getline(in, line)) Fail(path, "cannot be read or is empty");
  return ToLower(line).find("gt0") != std::string::npos ? ReadFrameNavigationCsv(path, skipped)
                                                         : ReadVehicleNavigationCsv(path, camera, crs, skipped);
}

NavigationCamera FrameCamera(const Store& store, NavigationCamera camera) {
  if (store.patches().empty()) return camera;
  if (const auto size = store.ReadSidecar(store.patches().front().id).frame_size) {
    camera.width = (*size)[0];
    camera.height = (*size)[1];
  }
  return camera;
}

GeoreferenceResult GeoreferenceMosaic(Store store, const std::map<std::string, FrameNavigation>& nav) {
  // The global record is rewritten from the sidecars read here: none may change meanwhile.
  const auto lock = LockStoreForChange(store, "rolamos georeference");
  if (!store.HasMosaic()) Fail(store.dir(), "has no mosaic.tif yet (run compose first)");
  // Correspondences: points around each frame's centre, in mosaic pixels and in map units.
  std::vector<cv::Point2d> mosaic_pts, map_pts;
  std::string crs;
  int frames = 0;
  for (const auto& entry : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(entry.id);
    if (!s.patch_to_global) continue;  // not placed in the mosaic
    if (!s.frame_size) Fail(store.PatchSidecarPath(entry.id), "has no \"frame_size\" (written by rolamos mosaic)");
    const cv::Size size((*s.frame_size)[0], (*s.frame_size)[1]);
    for (const auto& f : s.frames) {
      const FrameNavigation* n = FindFrameNavigation(nav, f.source);
      if (!n) continue;
      if (crs.empty()) crs = n->crs;
      if (n->crs != crs) Fail(store.dir(), "frames are in different CRSs (" + crs + ", " + n->crs + ")");
      AddNavigationPoints(*n, ToMatx(*s.patch_to_global) * ToMatx(f.frame_to_patch), size, &mosaic_pts, &map_pts);
      ++frames;
    }
  }
  if (frames < 2) Fail(store.dir(), "fewer than two placed frames have navigation");
  const std::optional<cv::Matx33d> M = FitSimilarity(mosaic_pts, map_pts);
  if (!M) Fail(store.dir(), "the navigation does not fit any similarity transform");
  GeoreferenceResult r;
  r.georef.crs = crs;
  r.georef.geotransform = {(*M)(0, 2), (*M)(0, 0), (*M)(0, 1), (*M)(1, 2), (*M)(1, 0), (*M)(1, 1)};
  std::vector<double> residuals;
  for (size_t i = 0; i < mosaic_pts.size(); i += 5) {  // frame centres
    const auto xy = r.georef.PixelToMap(mosaic_pts[i].x, mosaic_pts[i].y);
    residuals.push_back(std::hypot(xy[0] - map_pts[i].x, xy[1] - map_pts[i].y));
  }
  std::sort(residuals.begin(), residuals.end());
  r.frames_used = frames;
  r.median_residual_m = residuals[residuals.size() / 2];
  r.max_residual_m = residuals.back();
  WriteGeoref(store.MosaicPath(), r.georef);
  GlobalRecord global = store.global();
  global.georef = r.georef;
  global.georef->crs = CrsToWkt(crs);
  store.SetGlobal(global);
  return r;
}

Georef GeoreferenceLocal(Store store, double metres_per_frame_pixel) {
  const auto lock = LockStoreForChange(store, "rolamos georeference");
  if (!store.HasMosaic()) Fail(store.dir(), "has no mosaic.tif yet (run compose first)");
  if (!(metres_per_frame_pixel > 0) || !std::isfinite(metres_per_frame_pixel))
    Fail(store.dir(), "the local frame needs a positive pixel size (altitude / focal length)");
  const GlobalRecord global = store.global();
  // The first placed frame's centre, in mosaic pixels.
  std::optional<cv::Point2d> origin;
  for (const auto& entry : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(entry.id);
    if (!s.patch_to_global || s.frames.empty()) continue;
    const std::array<int, 2> size = s.frame_size.value_or(std::array<int, 2>{0, 0});
    const cv::Vec3d g = ToMatx(*s.patch_to_global) * ToMatx(s.frames.front().frame_to_patch) *
                        cv::Vec3d(0.5 * (size[0] - 1.0), 0.5 * (size[1] - 1.0), 1);
    origin = cv::Point2d(global.scale * g[0] / g[2] + 0.5 * global.scale - 0.5,
                         global.scale * g[1] / g[2] + 0.5 * global.scale - 0.5);
    break;
  }
  if (!origin) Fail(store.dir(), "has no placed frame to put the local frame's origin at");
  const double px = metres_per_frame_pixel / global.scale;
  Georef g;
  g.crs = kLocalCrsWkt;
  g.geotransform = {-origin->x * px, px, 0, origin->y * px, 0, -px};
  WriteGeoref(store.MosaicPath(), g);
  GlobalRecord updated = global;
  updated.georef = g;
  updated.georef->crs = CrsToWkt(g.crs);
  store.SetGlobal(updated);
  return g;
}

}  // namespace rolamos
