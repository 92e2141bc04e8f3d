#include "objects/detection_layers.h"

#include <cmath>
#include <map>

#include <ogr_spatialref.h>

namespace rolamos {

namespace {

nlohmann::json Ring(const cv::Rect2d& b, const std::optional<Georef>& georef) {
  nlohmann::json ring = nlohmann::json::array();
  for (const cv::Point2d p : {b.tl(), cv::Point2d(b.x + b.width, b.y), b.br(), cv::Point2d(b.x, b.y + b.height), b.tl()}) {
    if (georef) {
      const auto m = georef->PixelToMap(p.x, p.y);
      ring.push_back({m[0], m[1]});
    } else {
      ring.push_back({p.x, p.y});
    }
  }
  return ring;
}

nlohmann::json Collection(const std::string& name, const std::optional<Georef>& georef, nlohmann::json meta,
                          nlohmann::json features) {
  meta["coordinates"] = georef ? "map" : "pixel";
  meta["crs_wkt"] = georef ? georef->crs : "";
  nlohmann::json doc = {{"type", "FeatureCollection"}, {"name", name}, {"rolamos", meta}, {"features", features}};
  if (georef) {
    const std::string authority = CrsAuthorityCode(georef->crs);
    if (!authority.empty()) doc["crs"] = {{"type", "name"}, {"properties", {{"name", "urn:ogc:def:crs:" + authority}}}};
  }
  return doc;
}

// Share of each cell with data, from the coarsest level where a cell is 8 pixels or more.
std::vector<double> Coverage(const TiledImage& image, double cell_px, int cols, int rows) {
  int level = 0;
  while (level + 1 < image.num_levels() &&
         cell_px * double(image.info().levels[static_cast<size_t>(level + 1)].width) / double(image.width()) >= 8)
    ++level;
  const auto& l = image.info().levels[static_cast<size_t>(level)];
  const double fx = double(l.width) / double(image.width()), fy = double(l.height) / double(image.height());
  std::vector<double> share(static_cast<size_t>(cols) * rows, 1.0);
  if (image.info().channels != 2 && image.info().channels != 4) return share;
  for (int r = 0; r < rows; ++r) {
    const int y0 = int(std::floor(r * cell_px * fy)), y1 = std::min<int>(int(l.height), int(std::ceil((r + 1) * cell_px * fy)));
    if (y1 <= y0) continue;
    const cv::Mat strip = image.ReadRegion(level, cv::Rect(0, y0, int(l.width), y1 - y0));
    cv::Mat alpha;
    cv::extractChannel(strip, alpha, strip.channels() - 1);
    for (int c = 0; c < cols; ++c) {
      const int x0 = int(std::floor(c * cell_px * fx)), x1 = std::min<int>(int(l.width), int(std::ceil((c + 1) * cell_px * fx)));
      if (x1 <= x0) {
        share[static_cast<size_t>(r) * cols + c] = 0;
        continue;
      }
      const cv::Mat a = alpha(cv::Rect(x0, 0, x1 - x0, alpha.rows));
      // Cells at the image's edge are partly outside it: their share counts the part inside only.
      const double inside = std::min(1.0, (double(image.width()) - c * cell_px) / cell_px) *
                            std::min(1.0, (double(image.height()) - r * cell_px) / cell_px);
      share[static_cast<size_t>(r) * cols + c] = inside * double(cv::countNonZero(a)) / double(a.total());
    }
  }
  return share;
}

}  // namespace

double MetresPerUnit(const Georef& georef) {
  OGRSpatialReference srs;
  if (georef.crs.empty() || srs.importFromWkt(georef.crs.c_str()) != OGRERR_NONE || !srs.IsProjected()) return 0;
  return srs.GetLinearUnits();
}

nlohmann::json DetectionsGeoJson(const std::vector<MapDetection>& detections, const std::optional<Georef>& georef,
                                 const std::string& image_name, nlohmann::json meta) {
  nlohmann::json features = nlohmann::json::array();
  for (size_t i = 0; i < detections.size(); ++i) {
    const MapDetection& d = detections[i];
    nlohmann::json properties = {{"class", d.label},
                                 {"score", d.score},
                                 {"image", image_name},
                                 {"pixel_bbox", {d.box.x, d.box.y, d.box.width, d.box.height}},
                                 {"window_bbox", {d.window.x, d.window.y, d.window.width, d.window.height}},
                                 {"scores", d.scores}};
    features.push_back({{"type", "Feature"},
                        {"id", static_cast<int>(i + 1)},
                        {"geometry", {{"type", "Polygon"}, {"coordinates", {Ring(d.box, georef)}}}},
                        {"properties", properties}});
  }
  return Collection("rolamos_detections", georef, std::move(meta), std::move(features));
}

DensityLayer DensityGeoJson(const std::vector<MapDetection>& detections, const TiledImage& image,
                            const std::optional<Georef>& georef, double cell_px, const std::string& image_name) {
  const int cols = int(std::ceil(double(image.width()) / cell_px)), rows = int(std::ceil(double(image.height()) / cell_px));
  std::vector<std::map<std::string, int>> counts(static_cast<size_t>(cols) * rows);
  for (const auto& d : detections) {
    const int c = int((d.box.x + d.box.width / 2) / cell_px), r = int((d.box.y + d.box.height / 2) / cell_px);
    if (c >= 0 && c < cols && r >= 0 && r < rows) ++counts[static_cast<size_t>(r) * cols + c][d.label];
  }
  const std::vector<double> share = Coverage(image, cell_px, cols, rows);
  DensityLayer layer;
  const double metres = georef ? MetresPerUnit(*georef) : 0;
  layer.per_square_metre = metres > 0;
  // Area of one pixel: square metres from the geotransform, or 1 pixel.
  double pixel_area = 1;
  if (layer.per_square_metre) {
    const auto& g = georef->geotransform;
    pixel_area = std::abs(g[1] * g[5] - g[2] * g[4]) * metres * metres;
  }
  nlohmann::json features = nlohmann::json::array();
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const size_t i = static_cast<size_t>(r) * cols + c;
      // Cells mostly outside the map are left out, unless they hold detections: every one is counted.
      if (share[i] < 0.25 && (counts[i].empty() || share[i] <= 0)) continue;
      const double area = share[i] * cell_px * cell_px * pixel_area;
      const double unit = layer.per_square_metre ? area : area / 1e6;  // m^2 or megapixels
      int total = 0;
      nlohmann::json per_class = nlohmann::json::object(), densities = nlohmann::json::object();
      for (const auto& [label, n] : counts[i]) {
        total += n;
        per_class[label] = n;
        densities[label] = n / unit;
      }
      const cv::Rect2d box(c * cell_px, r * cell_px, std::min(cell_px, double(image.width()) - c * cell_px),
                           std::min(cell_px, double(image.height()) - r * cell_px));
      features.push_back({{"type", "Feature"},
                          {"id", static_cast<int>(i)},
                          {"geometry", {{"type", "Polygon"}, {"coordinates", {Ring(box, georef)}}}},
                          {"properties",
                           {{"count", total},
                            {"counts", per_class},
                            {"density", total / unit},
                            {"densities", densities},
                            {"area", area},
                            {"coverage", share[i]},
                            {"pixel_bbox", {box.x, box.y, box.width, box.height}}}}});
      ++layer.cells;
      layer.area += area;
    }
  nlohmann::json meta = {{"image", image_name},
                         {"cell_px", cell_px},
                         {"density_unit", layer.per_square_metre ? "per_m2" : "per_megapixel"},
                         {"area_unit", layer.per_square_metre ? "m2" : "px"}};
  layer.geojson = Collection("rolamos_density", georef, std::move(meta), std::move(features));
  return layer;
}

}  // namespace rolamos
