// What detection leaves in a store (docs/store-format.md, "objects/"): the detections as GeoJSON
// and the density layer over them, shared by the class model's and the box detector's search.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

struct MapDetection {
  std::string label;
  double score = 0;
  cv::Rect2d box;         // level-0 pixels of the image searched
  cv::Rect2d window;      // the window it was found in (level-0 pixels)
  nlohmann::json scores = nlohmann::json::object();  // every class's score, when there are several
};

// The FeatureCollection: one Polygon per detection, in map coordinates when georeferenced.
// `meta` becomes its "rolamos" member (with "coordinates" and "crs_wkt" added).
nlohmann::json DetectionsGeoJson(const std::vector<MapDetection>& detections, const std::optional<Georef>& georef,
                                 const std::string& image_name, nlohmann::json meta);

// Square cells of `cell_px` level-0 pixels over the image: in each, the detections whose centre
// falls in it (per class and all), the area with data (from the image's alpha, read through its
// tile cache at a coarse level) and their density: per square metre when the georeference is in
// metres, per megapixel otherwise. Cells with less than a quarter of data are left out unless
// they hold detections.
struct DensityLayer {
  nlohmann::json geojson;
  int cells = 0;
  double area = 0;        // with data: square metres or pixels
  bool per_square_metre = false;
};
DensityLayer DensityGeoJson(const std::vector<MapDetection>& detections, const TiledImage& image,
                            const std::optional<Georef>& georef, double cell_px, const std::string& image_name);

// Metres per map unit of a georeference's CRS when it is projected; 0 otherwise.
double MetresPerUnit(const Georef& georef);

}  // namespace rolamos
