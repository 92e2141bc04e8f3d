// The box detector over a store's mosaic or a patch, block by block through the tile cache.
#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "objects/box_evaluation.h"
#include "objects/detection_layers.h"
#include "objects/window_search.h"
#include "rolamos/box_detector.hpp"
#include "rolamos/error.hpp"
#include "rolamos/tile_cache.hpp"
#include "rolamos/tiled_image.hpp"
#include "util/files.h"
#include "util/memory.h"
#include "util/parallel_for.h"

namespace rolamos {

bool BoxSearchOptions::IsValid(std::string* error) const {
  if (patch < 0) {
    *error = "patch id cannot be negative (0 = the global mosaic)";
    return false;
  }
  if (block < 256 || block > 16384) {
    *error = "block must be in 256..16384 pixels";
    return false;
  }
  if (!(max_empty >= 0 && max_empty <= 1)) {
    *error = "max empty share must be in [0, 1]";
    return false;
  }
  if (!(cache_mb >= 16)) {
    *error = "tile cache must be at least 16 MB";
    return false;
  }
  if (!(density_cell >= 0)) {
    *error = "density cell must be positive (or 0 for 512 pixels)";
    return false;
  }
  if (std::isinf(min_score)) {
    *error = "minimum score must be a number";
    return false;
  }
  return true;
}

namespace {

// Gray with the "no data" filled by the mean of the data around it, so the border of the map
// is no edge to the detector; `valid` is where there is data.
cv::Mat GrayWithData(const cv::Mat& block, cv::Mat* valid) {
  cv::Mat gray;
  if (block.channels() == 2 || block.channels() == 4) {
    cv::Mat alpha;
    cv::extractChannel(block, alpha, block.channels() - 1);
    *valid = alpha > 0;
    gray = ToGray(block.channels() == 2 ? [&] { cv::Mat g; cv::extractChannel(block, g, 0); return g; }() : block);
    if (cv::countNonZero(*valid) == static_cast<int>(valid->total())) return gray;
    cv::Mat g, m, gs, ms;
    gray.convertTo(g, CV_32F);
    valid->convertTo(m, CV_32F, 1.0 / 255);
    g = g.mul(m);
    cv::GaussianBlur(g, gs, cv::Size(), 16);
    cv::GaussianBlur(m, ms, cv::Size(), 16);
    cv::Mat filled = gs / (ms + 1e-3);
    filled.convertTo(filled, gray.type());
    filled.copyTo(gray, ~*valid);
    return gray;
  }
  *valid = cv::Mat(block.size(), CV_8U, cv::Scalar(255));
  return ToGray(block);
}

}  // namespace

BoxSearchSummary DetectBoxesInStore(const Store& store, const BoxDetector& model, const BoxSearchOptions& options,
                                    const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("box search options", error);
  const auto start = std::chrono::steady_clock::now();
  const std::string path = store.ImagePath(options.patch);
  const std::string image_name = options.patch == 0 ? "mosaic" : "patch " + std::to_string(options.patch);
  TileCacheOptions cache_options;
  cache_options.max_memory_mb = options.cache_mb;
  const TiledImage image = TiledImage::Open(path, std::make_shared<TileCache>(cache_options));
  const double min_score = std::isnan(options.min_score) ? model.threshold() : options.min_score;
  // Blocks overlap by the largest window, so every box lies whole in one block's reach; a block
  // keeps the boxes whose centre is in its own part.
  const int margin = int(std::ceil(model.max_box() * 48.0 / 32.0)) + 16;
  const int b = options.block;
  const int cols = int((image.width() + b - 1) / b), rows = int((image.height() + b - 1) / b);
  std::vector<std::vector<BoxDetection>> found(static_cast<size_t>(cols) * rows);
  std::vector<long long> pixels(found.size(), 0);
  ParallelForOptions po;
  po.threads = options.threads;
  if (progress) po.on_progress = [&](long long done) { progress(0.95 * double(done) / double(found.size())); };
  ParallelFor(static_cast<long long>(found.size()), [&](long long i, int) {
    const int bx = int(i % cols) * b, by = int(i / cols) * b;
    const cv::Rect core(bx, by, int(std::min<long long>(b, image.width() - bx)), int(std::min<long long>(b, image.height() - by)));
    const cv::Rect reach = cv::Rect(bx - margin, by - margin, core.width + 2 * margin, core.height + 2 * margin) &
                           cv::Rect(0, 0, int(image.width()), int(image.height()));
    const cv::Mat block = image.ReadRegion(0, reach);
    cv::Mat valid;
    const cv::Mat gray = GrayWithData(block, &valid);
    const int with_data = cv::countNonZero(valid(core - reach.tl()));
    if (with_data == 0) return;
    pixels[static_cast<size_t>(i)] = with_data;
    for (const BoxDetection& d : model.Detect(gray, min_score)) {
      const cv::Point2d centre(d.box.x + d.box.width / 2 + reach.x, d.box.y + d.box.height / 2 + reach.y);
      if (!core.contains(cv::Point(int(std::floor(centre.x)), int(std::floor(centre.y))))) continue;
      const cv::Rect under = cv::Rect(d.box) & cv::Rect(0, 0, valid.cols, valid.rows);
      if (under.empty() || 1.0 - double(cv::countNonZero(valid(under))) / double(under.area()) > options.max_empty) continue;
      found[static_cast<size_t>(i)].push_back({d.box + cv::Point2d(reach.tl()), d.score});
    }
  }, po);

  std::vector<BoxDetection> all;
  for (const auto& f : found) all.insert(all.end(), f.begin(), f.end());
  // Blocks' parts do not overlap, but a box near a border can be found by both neighbours.
  std::vector<MapDetection> layer;
  const std::string& label = model.options().label;
  for (const BoxDetection& d : SuppressBoxes(std::move(all), model.options().nms_iou, model.options().nms_containment)) {
    // The window: the box and a quarter of its side around it, as the detector saw it.
    const cv::Rect2d window(d.box.x - d.box.width / 4, d.box.y - d.box.height / 4, d.box.width * 1.5, d.box.height * 1.5);
    layer.push_back({label, d.score, d.box, window, {{label, d.score}}});
  }

  BoxSearchSummary summary;
  const std::optional<Georef> georef = ReadGeoref(path);
  summary.georeferenced = georef.has_value();
  const std::string relative = std::filesystem::relative(path, store.dir()).string();
  const nlohmann::json doc = DetectionsGeoJson(layer, georef, image_name,
                                               {{"image", relative},
                                                {"level", 0},
                                                {"detector", model.Describe()["features"]},
                                                {"min_score", min_score},
                                                {"classes", {model.options().label}}});
  summary.output = options.output.empty() ? store.dir() + "/objects/detections.geojson" : options.output;
  std::filesystem::create_directories(std::filesystem::path(summary.output).parent_path());
  WriteFileAtomic(summary.output, doc.dump(1) + "\n");
  double cell = options.density_cell > 0 ? options.density_cell : 512;
  if (options.density_cell > 0 && georef && MetresPerUnit(*georef) > 0) {
    const auto& g = georef->geotransform;
    cell = options.density_cell / (std::sqrt(std::abs(g[1] * g[5] - g[2] * g[4])) * MetresPerUnit(*georef));
  }
  const DensityLayer density = DensityGeoJson(layer, image, georef, cell, relative);
  summary.density_output = options.density_output.empty()
                               ? std::filesystem::path(summary.output).parent_path().string() + "/density.geojson"
                               : options.density_output;
  WriteFileAtomic(summary.density_output, density.geojson.dump(1) + "\n");
  summary.density_cells = density.cells;
  summary.total_area = density.area;
  summary.windows = static_cast<long long>(found.size());
  for (long long p : pixels) summary.megapixels += double(p) / 1e6;
  summary.detections = static_cast<int>(layer.size());
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  summary.peak_rss_mb = PeakRssMb();
  if (progress) progress(1.0);
  return summary;
}

}  // namespace rolamos
