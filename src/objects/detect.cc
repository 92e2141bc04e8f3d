#include <algorithm>
#include <chrono>
#include <filesystem>

#include <opencv2/core.hpp>

#include "objects/bow_features.h"
#include "objects/detection_layers.h"
#include "objects/object_crop.h"
#include "objects/window_search.h"
#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "rolamos/objects.hpp"
#include "rolamos/tile_cache.hpp"
#include "rolamos/tiled_image.hpp"
#include "util/files.h"

namespace rolamos {

bool DetectOptions::IsValid(std::string* error) const {
  if (patch < 0) {
    *error = "patch id cannot be negative (0 = the global mosaic)";
    return false;
  }
  if (level < 0 || level > 30) {
    *error = "level must be in 0..30";
    return false;
  }
  if (window < 32 || window > 8192) {
    *error = "window must be in 32..8192 pixels";
    return false;
  }
  if (!(stride > 0.05 && stride <= 1.0)) {
    *error = "stride must be in (0.05, 1] of the window";
    return false;
  }
  if (!(nms_iou > 0 && nms_iou <= 1)) {
    *error = "non-maximum suppression overlap must be in (0, 1]";
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
  if (!std::isfinite(min_score)) {
    *error = "minimum score must be a number";
    return false;
  }
  return true;
}

namespace {

struct Detection {
  int cls = 0;
  std::string label;
  double score = 0;
  cv::Rect2d box0;     // level-0 pixels: the object's square, or the window
  cv::Rect2d window0;  // level-0 pixels: the window
  std::vector<ClassScore> scores;
};

// Greedy per class: the best window wins, windows overlapping it by more than `iou` go.
std::vector<Detection> Suppress(std::vector<Detection> d, double iou) {
  std::sort(d.begin(), d.end(), [](const Detection& a, const Detection& b) { return a.score > b.score; });
  std::vector<Detection> kept;
  for (auto& c : d) {
    bool overlapped = false;
    for (const auto& k : kept)
      if (k.cls == c.cls && BoxIou(k.box0, c.box0) > iou) {
        overlapped = true;
        break;
      }
    if (!overlapped) kept.push_back(std::move(c));
  }
  return kept;
}

// Share of a window's pixels that hold no data (alpha 0).
double EmptyShare(const cv::Mat& window) {
  if (window.channels() != 2 && window.channels() != 4) return 0;
  cv::Mat alpha;
  cv::extractChannel(window, alpha, window.channels() - 1);
  return 1.0 - double(cv::countNonZero(alpha)) / double(alpha.total());
}

}  // namespace

DetectSummary DetectObjects(const Store& store, const ObjectModel& model, const DetectOptions& options,
                            const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("detect options", error);
  const auto start = std::chrono::steady_clock::now();
  std::string path, image_name;
  path = store.ImagePath(options.patch);
  image_name = options.patch == 0 ? "mosaic" : "patch " + std::to_string(options.patch);
  TileCacheOptions cache_options;
  cache_options.max_memory_mb = options.cache_mb;
  const TiledImage image = TiledImage::Open(path, std::make_shared<TileCache>(cache_options));
  if (options.level >= image.num_levels())
    Fail(path, "has levels 0.." + std::to_string(image.num_levels() - 1) + ", not " + std::to_string(options.level));
  const auto& level = image.info().levels[static_cast<size_t>(options.level)];
  const double to0x = double(image.width()) / double(level.width);
  const double to0y = double(image.height()) / double(level.height);
  const int win_w = static_cast<int>(std::min<long long>(options.window, level.width));
  const int win_h = static_cast<int>(std::min<long long>(options.window, level.height));
  const int step = std::max(1, static_cast<int>(std::lround(options.window * options.stride)));
  std::vector<int> xs, ys;
  for (long long x = 0; x + win_w <= level.width; x += step) xs.push_back(static_cast<int>(x));
  for (long long y = 0; y + win_h <= level.height; y += step) ys.push_back(static_cast<int>(y));
  // The last row and column reach the edge.
  if (xs.back() + win_w < level.width) xs.push_back(static_cast<int>(level.width - win_w));
  if (ys.back() + win_h < level.height) ys.push_back(static_cast<int>(level.height - win_h));

  DetectSummary summary;
  const long long total = static_cast<long long>(xs.size()) * static_cast<long long>(ys.size());
  std::vector<Detection> found;
  const bool object_boxes = model.features().object_view;
  // A row of windows at a time: memory holds one row, the tile cache the rest.
  for (int y : ys) {
    std::vector<cv::Mat> windows;
    std::vector<cv::Rect> rects;
    for (int x : xs) {
      const cv::Rect r(x, y, win_w, win_h);
      cv::Mat w = image.ReadRegion(options.level, r);
      ++summary.windows;
      if (EmptyShare(w) > options.max_empty) {
        ++summary.skipped;
        continue;
      }
      windows.push_back(std::move(w));
      rects.push_back(r);
    }
    const auto scores = model.ClassifyAll(windows);
    auto level0 = [&](const cv::Rect2d& r) { return cv::Rect2d(r.x * to0x, r.y * to0y, r.width * to0x, r.height * to0y); };
    for (size_t i = 0; i < scores.size(); ++i) {
      const ClassScore& best = scores[i].front();
      if (!(best.score > options.min_score)) continue;
      Detection d;
      d.label = best.label;
      d.cls = static_cast<int>(std::find(model.classes().begin(), model.classes().end(), best.label) - model.classes().begin());
      d.score = best.score;
      d.window0 = level0(rects[i]);
      d.box0 = d.window0;
      // A model that describes the object found in each window scores the window by that object,
      // wherever it lies in it: the detection is the object's square (what the model described),
      // so overlapping windows that found one object agree on its place.
      if (object_boxes) {
        const cv::Rect box = ObjectBox(ToBgr8(windows[i])) & cv::Rect(0, 0, windows[i].cols, windows[i].rows);
        if (!box.empty()) d.box0 = level0(cv::Rect2d(rects[i].x + box.x, rects[i].y + box.y, box.width, box.height));
      }
      d.scores = scores[i];
      found.push_back(std::move(d));
    }
    if (progress) progress(total > 0 ? double(summary.windows) / double(total) : 1.0);
  }
  const std::vector<Detection> kept = Suppress(std::move(found), options.nms_iou);

  const std::optional<Georef> georef = ReadGeoref(path);
  summary.georeferenced = georef.has_value();
  std::vector<MapDetection> layer;
  for (const Detection& d : kept) {
    MapDetection m{d.label, d.score, d.box0, d.window0};
    for (const auto& s : d.scores) m.scores[s.label] = s.score;
    layer.push_back(std::move(m));
  }
  const std::string relative = std::filesystem::relative(path, store.dir()).string();
  const nlohmann::json doc = DetectionsGeoJson(layer, georef, image_name,
                                               {{"image", relative},
                                                {"level", options.level},
                                                {"window", options.window},
                                                {"stride", options.stride},
                                                {"min_score", options.min_score},
                                                {"classes", model.classes()}});
  summary.output = options.output.empty() ? store.dir() + "/objects/detections.geojson" : options.output;
  std::filesystem::create_directories(std::filesystem::path(summary.output).parent_path());
  WriteFileAtomic(summary.output, doc.dump(1) + "\n");
  // The density layer beside it, four windows to a cell.
  const DensityLayer density = DensityGeoJson(layer, image, georef, 2.0 * options.window * std::max(to0x, 1.0), relative);
  WriteFileAtomic(std::filesystem::path(summary.output).parent_path().string() + "/density.geojson", density.geojson.dump(1) + "\n");
  summary.detections = static_cast<int>(kept.size());
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos
