// Detection of one kind of object by its box (Nephrops burrows, in the seafloor frames of
// underwater-TV surveys): a sliding-window detector trained from boxed frames (YOLO label files).
// Each level of an image pyramid (2^(1/4) apart) is described by cells of 8 pixels: gradient
// orientation histograms normalised over their neighbours (as Felzenszwalb's HOG) and the
// cell's brightness against its surroundings, so vignetting and light cones do not change the
// description. A window of 6 x 6 cells holds a box of 4 x 4 cells; a linear SVM, trained on
// the boxes and on background windows mined from the frames (the hard ones in a second round),
// scores it; overlapping windows keep the best. The peer (`features = "hog"`) is the classic
// Dalal-Triggs descriptor (OpenCV's HOGDescriptor) through the same training and search.
#pragma once

#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "rolamos/objects.hpp"
#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

inline constexpr const char* kBoxDetectorFormat = "rolamos-box-detector";
inline constexpr int kBoxDetectorVersion = 1;
// The lowest score evaluation keeps (the tail of the precision-recall curve): SVM margins below
// it are background.
inline constexpr double kBoxCurveScore = -1.0;

// One frame and its boxes (pixels), from DIR/images and DIR/labels_gt.
struct BoxedImage {
  std::string path;
  std::vector<cv::Rect2d> boxes;
  std::string station;  // the survey station it belongs to (see GroupStations)
  long long time = 0;   // capture time from the name (seconds), -1 when the name has none
};
// Reads DIR/images/*.{jpg,png,...} and, for each, DIR/labels_gt/<stem>.txt holding lines
// "class cx cy w h" normalised to the image (YOLO). A frame without a label file has no boxes.
// Throws Error naming the file and line of a malformed label.
std::vector<BoxedImage> ReadBoxedFolder(const std::string& dir);
// Frames whose names carry a capture time (..._D2023-06-03T16-26-07...) are grouped into
// stations: a gap longer than `gap_seconds` starts a new one. Frames without a time are each
// their own station. Consecutive frames are near-duplicates, so validation splits by station.
void GroupStations(std::vector<BoxedImage>* images, double gap_seconds = 600);
// Assigns stations to `folds` folds of similar frame counts (largest first); returns the fold of
// each image. Fewer stations than folds gives one fold per station.
std::vector<int> StationFolds(const std::vector<BoxedImage>& images, int folds);

struct BoxDetectorOptions {
  std::string label = "object";     // the class it reports (YOLO files hold numbers, not names)
  std::string features = "cells";   // cells (ours) or hog (OpenCV's HOGDescriptor, the peer)
  double min_box = 24;               // smallest box side searched, pixels (smaller boxes match at IoU > 0.5)
  double max_box = 200;              // largest
  int scales_per_octave = 4;         // pyramid levels per halving
  double c = 0.01;                   // SVM regularisation
  int negatives_per_image = 80;      // random background windows per frame
  int hard_negative_rounds = 2;      // rounds of mining the background windows it mistakes (a third adds nothing)
  int hard_negatives_per_image = 150;
  double nms_iou = 0.35;             // overlapping detections above this keep the best
  // A detection lying inside a better one (or around it) by more than this share of its area
  // goes: the dark opening and the whole burrow around it are one object (nested true boxes are
  // 0.4 % of the Nephrops set's).
  double nms_containment = 0.7;
  int threads = 0;                   // 0: one per core
  unsigned seed = 1;

  bool IsValid(std::string* error) const;
};

struct BoxDetection {
  cv::Rect2d box;   // pixels of the image it was found in
  double score = 0; // SVM decision value
};

class BoxDetector {
 public:
  // Trains on the frames; the operating threshold is the score of the best F1 on them.
  static BoxDetector Train(const std::vector<BoxedImage>& images, const BoxDetectorOptions& options,
                           const ProgressFn& progress = {});
  // Throws Error for a missing or foreign file.
  static BoxDetector Load(const std::string& path);
  void Save(const std::string& path) const;  // .yml.gz or .yml

  // Every window above `min_score` (after suppression), best first. BGR, BGRA or gray, 8 or 16 bits.
  std::vector<BoxDetection> Detect(const cv::Mat& image, double min_score) const;
  // Detect at the operating threshold.
  std::vector<BoxDetection> Detect(const cv::Mat& image) const { return Detect(image, threshold()); }
  double threshold() const;
  const BoxDetectorOptions& options() const;
  // Largest box side it reports, pixels: blocks read from a mosaic overlap by this much.
  double max_box() const;
  nlohmann::json Describe() const;

 private:
  struct Impl;
  std::shared_ptr<const Impl> impl_;
};

// True when `path` holds a box detector (not a class model).
bool IsBoxDetectorFile(const std::string& path);

// Precision, recall and AP at IoU 0.5 (Pascal VOC's all-point average precision: each true box
// matches at most one detection, the best-scored first).
struct BoxEvaluation {
  double ap50 = 0, precision = 0, recall = 0, f1 = 0;
  double threshold = 0;  // the score precision/recall/F1 are counted at
  long long true_boxes = 0, detections = 0, true_positives = 0;
  int images = 0;
};
BoxEvaluation EvaluateBoxes(const std::vector<std::vector<BoxDetection>>& detections,
                            const std::vector<std::vector<cv::Rect2d>>& truth, double threshold);

// A detector on boxed frames (every core): AP50 over every detection down to kBoxCurveScore,
// precision, recall and F1 at its threshold.
BoxEvaluation EvaluateBoxDetector(const BoxDetector& detector, const std::vector<BoxedImage>& images,
                                  const ProgressFn& progress = {});

struct BoxValidation {
  BoxEvaluation pooled;               // every frame, each scored by the model not trained on its station
  std::vector<BoxEvaluation> folds;   // per fold
  std::vector<std::vector<std::string>> fold_stations;
  double seconds_train = 0, seconds_detect = 0, megapixels = 0;
};
// Station-wise cross-validation: frames of one station are never in both training and validation.
BoxValidation CrossValidateBoxes(const std::vector<BoxedImage>& images, const BoxDetectorOptions& options,
                                 int folds, const ProgressFn& progress = {});

nlohmann::json ToJson(const BoxEvaluation& e);
// The pooled evaluation's fields, "validation": "by station", "folds" (each with its
// "stations"), "seconds_train", "seconds_detect" and "megapixels_per_second".
nlohmann::json ToJson(const BoxValidation& v);

// Detection over a store's mosaic (or a patch) in blocks read through the tile cache, so speed
// and memory do not grow with the map. Writes the detections as GeoJSON (the schema of
// DetectObjects) and a density layer: a grid of cells with the count, the mapped area and the
// count per square metre when the image is georeferenced in metres (per megapixel otherwise).
struct BoxSearchOptions {
  int patch = 0;                 // 0: the global mosaic
  double min_score = std::numeric_limits<double>::quiet_NaN();  // NaN: the model's threshold
  int block = 1024;              // pixels read at a time (plus a margin of the largest box)
  double max_empty = 0.5;        // detections with more "no data" than this under them are dropped
  double cache_mb = 256;
  double density_cell = 0;       // side of a density cell: metres when georeferenced, pixels otherwise; 0 = 512 px
  std::string output;            // default: <store>/objects/detections.geojson
  std::string density_output;    // default: <store>/objects/density.geojson
  int threads = 0;

  bool IsValid(std::string* error) const;
};
struct BoxSearchSummary : DetectSummary {
  double megapixels = 0;         // of map searched
  double peak_rss_mb = 0;
  int density_cells = 0;
  double total_area = 0;         // square metres (georeferenced) or pixels
  std::string density_output;
};
BoxSearchSummary DetectBoxesInStore(const Store& store, const BoxDetector& model, const BoxSearchOptions& options,
                                    const ProgressFn& progress = {});

}  // namespace rolamos
