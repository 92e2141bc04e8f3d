// Object identification on the map (the paper's section 4.5): a bag of visual words over dense
// SIFT with colour, and one SVM per class against all others, trained from a folder per class.
// Detection runs the classifier over a store's mosaic or patches with sliding windows read
// through the tile cache, suppresses overlapping windows, and writes GeoJSON into the store.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

inline constexpr const char* kObjectModelFormat = "rolamos-object-model";
// 2 added the colour statistics, places, orientations and linear weight vectors: a reader of
// version 1 would misread such a model, so it is told to refuse it. Version 1 files still load.
inline constexpr int kObjectModelVersion = 2;
inline constexpr int kObjectModelOldestVersion = 1;
// A class folder with this name holds negatives only: it teaches every SVM what is not an
// object (bare seafloor) and is never reported.
inline constexpr const char* kBackgroundClass = "background";

struct ObjectFeatureOptions {
  int image_size = 192;                   // samples are resized to this square first
  std::string descriptor = "sift";        // sift (gray) or opponent-sift (colour, 3 x 128)
  int grid_step = 6;                      // dense SIFT grid step, pixels at image_size
  std::vector<int> patch_sizes = {12, 24, 36};  // SIFT support diameters, pixels at image_size
  int pyramid_levels = 2;                 // spatial pyramid: 1 = whole image, 2 = + 2 x 2 cells
  bool centre_cell = true;                // one more cell: the central half, where the object is
  // A second view: the square around the blob that stands out near the centre, described at the
  // same size whatever the object's (its whole and its quarters, words and colour). For crops
  // centred on their object: with fisher and a linear kernel, 78 % on validation against 74 % for
  // the default; off by default because sliding windows are not centred (more false detections).
  bool object_view = true;
  // vlad: per visual word, the sum of the descriptors' residuals to it, power- and
  // L2-normalised (the best on validation data: 74 % against 68 % for plain counts);
  // bow: word counts (histograms, the paper's, for the chi-square kernel).
  // fisher: Fisher vectors over a Gaussian mixture of PCA-reduced descriptors (pca_dims).
  std::string encoding = "fisher";
  int pca_dims = 64;                      // fisher only
  // fisher only: a second local descriptor, the mean and spread of L, a, b in the 4 x 4
  // subregions of every dense patch, with its own Fisher codebook (colour_pca_dims).
  bool colour_statistics = true;
  int colour_pca_dims = 48;
  // fisher only: each descriptor's place in the sample (x, y in -0.5..0.5) joins it in the
  // mixture, so the words also say where they were seen (spatially augmented Fisher vectors).
  bool spatial_coordinates = true;
  // The description averaged over the sample's orientations: 1 (as it is), 2 (and its mirror
  // image), 4 (its quarter turns) or 8 (both). A downward-looking camera sees an object in any
  // orientation; the turned descriptors are permutations of the extracted ones.
  int orientations = 2;
  int hue_bins = 0, saturation_bins = 0;  // colour histogram per pyramid cell; 0 = none
  double colour_weight = 1.0;             // of the colour part against the words

  bool IsValid(std::string* error) const;
};

struct ObjectTrainOptions {
  ObjectFeatureOptions features;
  int vocabulary = 64;           // visual words (k-means); ~400 suits bow, ~64 vlad
  int kmeans_samples = 120000;   // descriptors sampled for k-means
  std::string kernel = "linear"; // chi2 (bow only), rbf or linear
  int folds = 5;                 // cross-validation folds for C (and gamma)
  // What those folds choose by: accuracy, or balanced (the mean of the classes' recalls, which
  // gives rare classes their weight).
  std::string select_by = "accuracy";
  unsigned seed = 1;

  bool IsValid(std::string* error) const;
};

struct ClassScore {
  std::string label;
  double score = 0;  // the class's SVM decision value: > 0 means "this class, not the others"
};

// Images in a folder per class, in a stable order.
struct LabelledImages {
  std::vector<std::string> classes;  // folder names, sorted; background (if any) included
  std::vector<std::string> files;
  std::vector<int> labels;           // index into classes
};
// Throws Error for a missing folder, no class folders, or an empty class folder.
LabelledImages ReadLabelledFolder(const std::string& dir);
// Several folders as one set (train and validation together), classes joined by name.
LabelledImages ReadLabelledFolders(const std::vector<std::string>& dirs);
// The images at `rows` of a set.
LabelledImages Subset(const LabelledImages& data, const std::vector<int>& rows);

// Repeated stratified k-fold cross-validation: each repeat splits every class into `folds`
// parts at random (its own seed); each part is classified by a model trained on the others.
struct ObjectValidation {
  std::vector<std::string> classes;
  std::vector<double> fold_accuracy;     // one per fold and repeat
  double mean = 0, spread = 0;           // of fold_accuracy (spread: sample standard deviation)
  std::vector<double> recall;            // per class, pooled over every fold and repeat
  std::vector<std::vector<int>> confusion;  // pooled, [true][predicted]
  int images = 0, folds = 0, repeats = 0;
  double seconds = 0;
};
// The fold of every image: each class dealt evenly round `folds` folds in a random order.
std::vector<int> StratifiedFolds(const LabelledImages& data, int folds, unsigned seed);
// Repeat r uses the folds of StratifiedFolds(data, folds, options.seed + 1000 r).
ObjectValidation CrossValidateObjects(const LabelledImages& data, const ObjectTrainOptions& options, int folds,
                                      int repeats, const ProgressFn& progress = {});
// Every field by its name ("mean", "spread", "fold_accuracy", "classes", "recall", ...).
nlohmann::json ToJson(const ObjectValidation& v);

class ObjectModel {
 public:
  // Trains on `data_dir` (a folder per class). Unreadable images stop training with their name.
  static ObjectModel Train(const std::string& data_dir, const ObjectTrainOptions& options,
                           const ProgressFn& progress = {});
  // The same from images already listed (`where` names them in errors).
  static ObjectModel Train(const LabelledImages& data, const ObjectTrainOptions& options,
                           const ProgressFn& progress = {}, const std::string& where = "the training images");
  // Throws Error for a missing, truncated or foreign file, or another format version.
  static ObjectModel Load(const std::string& path);
  void Save(const std::string& path) const;  // .yml.gz (compressed) or .yml

  // The classes it reports (the background class is not one of them).
  const std::vector<std::string>& classes() const;
  // How it describes an image (as trained).
  const ObjectFeatureOptions& features() const;
  // Every reported class's score for one image (BGR or BGRA, any size), best first.
  std::vector<ClassScore> Classify(const cv::Mat& image) const;
  // The same for many images, on every core.
  std::vector<std::vector<ClassScore>> ClassifyAll(const std::vector<cv::Mat>& images) const;
  // Settings, classes, training counts and the cross-validated SVM parameters.
  nlohmann::json Describe() const;

 private:
  struct Impl;
  std::shared_ptr<const Impl> impl_;
};

struct ObjectEvaluation {
  std::vector<std::string> classes;
  std::vector<std::vector<int>> confusion;  // [true][predicted]
  std::vector<double> precision, recall;
  std::vector<int> support;
  double accuracy = 0;
  int images = 0;
  double seconds = 0;
};
// Classifies every image of `data_dir` (a folder per class; classes the model does not know
// are an error) and compares with the folder labels.
ObjectEvaluation EvaluateObjects(const ObjectModel& model, const std::string& data_dir,
                                 const ProgressFn& progress = {});
ObjectEvaluation EvaluateObjects(const ObjectModel& model, const LabelledImages& data, const ProgressFn& progress = {},
                                 const std::string& where = "the images");
// "accuracy: NN.N %", then per-class precision/recall and the confusion matrix.
std::string FormatEvaluation(const ObjectEvaluation& e);

struct DetectOptions {
  int patch = 0;             // 0: the global mosaic; otherwise that patch
  int level = 0;             // pyramid level the windows are cut from
  int window = 256;          // window side, pixels at that level
  double stride = 0.5;       // window step, as a fraction of the window
  double min_score = 0.0;    // decision value a window needs to count as an object
  double nms_iou = 0.3;      // overlapping detections of a class above this keep the best
  double max_empty = 0.5;    // windows with more "no data" than this are skipped
  double cache_mb = 256;     // tile cache bound
  std::string output;        // default: <store>/objects/detections.geojson

  bool IsValid(std::string* error) const;
};

struct DetectSummary {
  long long windows = 0, skipped = 0;
  int detections = 0;
  double seconds = 0;
  std::string output;
  bool georeferenced = false;
};
DetectSummary DetectObjects(const Store& store, const ObjectModel& model, const DetectOptions& options,
                            const ProgressFn& progress = {});

}  // namespace rolamos
