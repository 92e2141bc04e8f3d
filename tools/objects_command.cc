#include <cmath>
#include <cstdio>
#include <mutex>

#include "command.h"
#include "rolamos/box_detector.hpp"
#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"
#include "util/files.h"
#include "util/progress.h"

#include <opencv2/imgcodecs.hpp>

namespace rolamos::cli {

namespace {

struct TrainSwitches {
  std::vector<std::string> data;
  std::string boxes, output;
  ObjectTrainOptions options;
  BoxDetectorOptions box_options;
  bool quiet = false;
};

struct EvalSwitches {
  std::string data, boxes, model;
  bool quiet = false, json = false;
};

struct ValidateSwitches {
  std::vector<std::string> data;
  std::string boxes;
  int folds = 5, repeats = 1;
  ObjectTrainOptions options;
  BoxDetectorOptions box_options;
  bool quiet = false, json = false;
};

struct DetectSwitches {
  std::string store, model, frames;
  DetectOptions options;
  BoxSearchOptions box_options;
  bool quiet = false;
};

// Library progress arrives from worker threads: one bar, redrawn under a lock.
ProgressFn BarFor(Progress* bar, std::mutex* mutex) {
  return [bar, mutex](double fraction) {
    std::lock_guard<std::mutex> lock(*mutex);
    bar->Update(fraction);
  };
}

// The class model's training settings, shared by train and validate.
void AddClassModelOptions(CLI::App* app, ObjectTrainOptions* o) {
  app->add_option("--select-by", o->select_by, "what the folds choose the SVM's C by: accuracy, or balanced (mean of the classes' recalls; each class's decision also gets an offset fitted on the held-out scores, so that rare classes are predicted)")
      ->capture_default_str();
  app->add_option("--vocabulary", o->vocabulary, "visual words (k-means)")->capture_default_str();
  app->add_option("--descriptor", o->features.descriptor, "sift (gray) or opponent-sift (colour)")
      ->capture_default_str();
  app->add_option("--encoding", o->features.encoding, "bow (word histograms), vlad (residuals to the words) or fisher (Fisher vectors: a Gaussian mixture of --vocabulary components)")
      ->capture_default_str();
  app->add_option("--kernel", o->kernel, "SVM kernel: chi2, rbf or linear")->capture_default_str();
  app->add_option("--folds", o->folds, "cross-validation folds for the SVM parameters")->capture_default_str();
  app->add_option("--image-size", o->features.image_size, "samples are resized to this square")->capture_default_str();
  app->add_option("--grid-step", o->features.grid_step, "dense SIFT grid step, pixels")->capture_default_str();
  app->add_option("--patch-sizes", o->features.patch_sizes, "SIFT support diameters, pixels")
      ->capture_default_str()->delimiter(',');
  app->add_option("--pyramid-levels", o->features.pyramid_levels, "spatial pyramid levels (1..3)")->capture_default_str();
  app->add_flag("!--no-centre-cell", o->features.centre_cell, "no separate words for the central half");
  app->add_option("--hue-bins", o->features.hue_bins, "colour histogram hue bins (0 = no colour)")->capture_default_str();
  app->add_option("--saturation-bins", o->features.saturation_bins, "colour histogram saturation bins")->capture_default_str();
  app->add_option("--colour-weight", o->features.colour_weight, "weight of colour against words")->capture_default_str();
  app->add_flag("--object-view,!--no-object-view", o->features.object_view,
                  "also describe the square around the object found near the centre (on by default)");
  app->add_option("--pca-dims", o->features.pca_dims, "descriptor dimensions kept by PCA (fisher)")->capture_default_str();
  app->add_flag("--colour-statistics,!--no-colour-statistics", o->features.colour_statistics,
                  "also describe each patch by the mean and spread of its colours (fisher; on by default)");
  app->add_option("--colour-pca-dims", o->features.colour_pca_dims, "colour statistics dimensions kept by PCA")
      ->capture_default_str();
  app->add_flag("--spatial-coordinates,!--no-spatial-coordinates", o->features.spatial_coordinates,
                  "each descriptor's place joins it in the Gaussian mixture (fisher; on by default)");
  app->add_option("--orientations", o->features.orientations,
                    "describe the image in 1, 2 (mirrored), 4 (turned) or 8 orientations, averaged")->capture_default_str();
  app->add_option("--kmeans-samples", o->kmeans_samples, "descriptors sampled for k-means")->capture_default_str();
  app->add_option("--seed", o->seed, "random seed (sampling, k-means)")->capture_default_str();
}

// The Fisher-only additions are on by default: with another encoding, they are off unless asked for.
void FisherOnlyDefaults(CLI::App* app, ObjectTrainOptions* o) {
  if (o->features.encoding == "fisher") return;
  if (app->count("--colour-statistics") + app->count("--no-colour-statistics") == 0) o->features.colour_statistics = false;
  if (app->count("--spatial-coordinates") + app->count("--no-spatial-coordinates") == 0) o->features.spatial_coordinates = false;
}

// The box detector's training settings, shared by train and validate.
void AddBoxOptions(CLI::App* app, BoxDetectorOptions* o) {
  app->add_option("--label", o->label, "the class a box detector reports")->capture_default_str();
  app->add_option("--features", o->features, "box detector: cells (ours) or hog (OpenCV's HOG, the peer)")->capture_default_str();
  app->add_option("--min-box", o->min_box, "box detector: smallest box side searched, pixels")->capture_default_str();
  app->add_option("--max-box", o->max_box, "box detector: largest box side searched, pixels")->capture_default_str();
  app->add_option("--c", o->c, "box detector: SVM cost")->capture_default_str();
  app->add_option("--hard-negative-rounds", o->hard_negative_rounds, "box detector: rounds of mining mistaken background")
      ->capture_default_str();
  app->add_option("--nms-iou", o->nms_iou, "overlap above which the weaker detection goes")->capture_default_str();
  app->add_option("--nms-containment", o->nms_containment, "box detector: share of a box inside a better one above which it goes")
      ->capture_default_str();
}

int RunTrainBoxes(const TrainSwitches& s) {
  std::string error;
  if (!s.box_options.IsValid(&error)) Fail("objects train", error);
  const std::vector<BoxedImage> images = ReadBoxedFolder(s.boxes);
  Progress bar("train", s.quiet);
  std::mutex mutex;
  const BoxDetector model = BoxDetector::Train(images, s.box_options, BarFor(&bar, &mutex));
  model.Save(s.output);
  bar.Done();
  const auto d = model.Describe();
  std::printf("%s: box detector of %s (%s features), %lld boxes in %zu frames, threshold %.3f, F1 on its training frames %.3f, trained in %.1f s\n",
              s.output.c_str(), s.box_options.label.c_str(), s.box_options.features.c_str(),
              d["training"]["boxes"].get<long long>(), images.size(), model.threshold(),
              d["training"]["training_f1"].get<double>(), bar.ElapsedSeconds());
  return 0;
}

void PrintBoxEvaluation(const char* what, const BoxEvaluation& e) {
  std::printf("%s: AP50 %.3f, precision %.3f, recall %.3f, F1 %.3f (%lld of %lld boxes found, %lld detections, %d frames)\n",
              what, e.ap50, e.precision, e.recall, e.f1, e.true_positives, e.true_boxes, e.detections, e.images);
}

int RunEvalBoxes(const EvalSwitches& s) {
  const std::vector<BoxedImage> images = ReadBoxedFolder(s.boxes);
  Progress bar("eval", s.quiet);
  std::mutex mutex;
  const BoxDetector model = BoxDetector::Load(s.model);
  const BoxEvaluation e = EvaluateBoxDetector(model, images, BarFor(&bar, &mutex));
  bar.Done();

  if (s.json)
    std::printf("%s\n", ToJson(e).dump(1).c_str());
  else
    PrintBoxEvaluation(s.boxes.c_str(), e);
  return 0;
}

int RunValidateBoxes(const ValidateSwitches& s) {
  const std::vector<BoxedImage> images = ReadBoxedFolder(s.boxes);
  Progress bar("validate", s.quiet);
  std::mutex mutex;
  std::string error;
  if (!s.box_options.IsValid(&error)) Fail("objects validate", error);
  const BoxValidation v = CrossValidateBoxes(images, s.box_options, s.folds, BarFor(&bar, &mutex));
  bar.Done();
  const nlohmann::json j = ToJson(v);
  if (s.json) {
    std::printf("%s\n", j.dump(1).c_str());
    return 0;
  }
  PrintBoxEvaluation("by station, pooled", v.pooled);
  for (size_t f = 0; f < v.folds.size(); ++f) {
    std::string stations;
    for (const auto& st : v.fold_stations[f]) stations += (stations.empty() ? "" : ", ") + st;
    PrintBoxEvaluation(("  fold " + std::to_string(f + 1) + " (" + std::to_string(v.fold_stations[f].size()) +
                        " stations: " + stations + ")").c_str(), v.folds[f]);
  }
  std::printf("training %.1f s, detection %.2f Mpx/s\n", v.seconds_train, j["megapixels_per_second"].get<double>());
  return 0;
}

int RunValidate(const ValidateSwitches& s) {
  if (!s.boxes.empty()) return RunValidateBoxes(s);
  std::string error;
  if (!s.options.IsValid(&error)) Fail("objects validate", error);
  const LabelledImages data = ReadLabelledFolders(s.data);
  Progress bar("validate", s.quiet);
  std::mutex mutex;
  const ObjectValidation v = CrossValidateObjects(data, s.options, s.folds, s.repeats, BarFor(&bar, &mutex));
  bar.Done();
  if (s.json) {
    const nlohmann::json j = ToJson(v);
    std::printf("%s\n", j.dump(1).c_str());
    return 0;
  }
  std::printf("cross-validated accuracy %.1f %% +- %.1f (%d folds x %d repeats, stratified, %d images, %.0f s)\n",
              100 * v.mean, 100 * v.spread, v.folds, v.repeats, v.images, v.seconds);
  for (size_t c = 0; c < v.classes.size(); ++c) std::printf("  %-20s recall %5.1f %%\n", v.classes[c].c_str(), 100 * v.recall[c]);
  return 0;
}

int RunTrain(const TrainSwitches& s) {
  if (!s.boxes.empty()) return RunTrainBoxes(s);
  std::string error;
  if (!s.options.IsValid(&error)) Fail("objects train", error);
  Progress bar("train", s.quiet);
  std::mutex mutex;
  // Several folders train one model (train and validation together, once settings are chosen).
  ObjectModel model = s.data.size() == 1 ? ObjectModel::Train(s.data[0], s.options, BarFor(&bar, &mutex))
                                         : ObjectModel::Train(ReadLabelledFolders(s.data), s.options, BarFor(&bar, &mutex));
  model.Save(s.output);
  bar.Done();
  const auto d = model.Describe();
  std::string classes;
  for (const auto& c : model.classes()) classes += (classes.empty() ? "" : ", ") + c;
  std::printf("%s: %zu classes (%s), %d words, %d dims, %s kernel, trained in %.1f s\n", s.output.c_str(),
              model.classes().size(), classes.c_str(), d["features"]["words"].get<int>(),
              d["features"]["dims"].get<int>(), s.options.kernel.c_str(), bar.ElapsedSeconds());
  return 0;
}

int RunEval(const EvalSwitches& s) {
  if (!s.boxes.empty()) return RunEvalBoxes(s);
  const ObjectModel model = ObjectModel::Load(s.model);
  Progress bar("eval", s.quiet);
  std::mutex mutex;
  const ObjectEvaluation e = EvaluateObjects(model, s.data, BarFor(&bar, &mutex));
  bar.Done();
  if (s.json) {
    nlohmann::json j = {{"accuracy", e.accuracy}, {"images", e.images}, {"seconds", e.seconds},
                        {"classes", e.classes}, {"precision", e.precision}, {"recall", e.recall},
                        {"support", e.support}, {"confusion", e.confusion}};
    std::printf("%s\n", j.dump(1).c_str());
  } else {
    std::printf("%s", FormatEvaluation(e).c_str());
  }
  return 0;
}

int RunDetectFrames(const DetectSwitches& s) {
  const BoxDetector model = BoxDetector::Load(s.model);
  const std::vector<BoxedImage> images = ReadBoxedFolder(s.frames);
  Progress bar("detect", s.quiet);
  nlohmann::json out = nlohmann::json::array();
  long long boxes = 0;
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat image = cv::imread(images[i].path, cv::IMREAD_UNCHANGED);
    if (image.empty()) Fail(images[i].path, "cannot be decoded as an image");
    nlohmann::json list = nlohmann::json::array();
    for (const auto& d : model.Detect(image, std::isnan(s.box_options.min_score) ? model.threshold() : s.box_options.min_score))
      list.push_back({{"class", model.options().label}, {"score", d.score}, {"bbox", {d.box.x, d.box.y, d.box.width, d.box.height}}});
    boxes += static_cast<long long>(list.size());
    out.push_back({{"image", images[i].path}, {"width", image.cols}, {"height", image.rows}, {"detections", list}});
    bar.Update(double(i + 1) / double(images.size()));
  }
  bar.Done();
  const std::string output = s.box_options.output.empty() ? "detections.json" : s.box_options.output;
  WriteFileAtomic(output, out.dump(1) + "\n");
  std::printf("%s: %lld detections in %zu frames, %.1f s\n", output.c_str(), boxes, images.size(), bar.ElapsedSeconds());
  return 0;
}

int RunDetectBoxes(const DetectSwitches& s) {
  std::string error;
  if (!s.box_options.IsValid(&error)) Fail("objects detect", error);
  const BoxDetector model = BoxDetector::Load(s.model);
  Progress bar("detect", s.quiet);
  std::mutex mutex;
  const BoxSearchSummary r = DetectBoxesInStore(Store::Open(s.store), model, s.box_options, BarFor(&bar, &mutex));
  bar.Done();
  std::printf("%s: %d detections of %s over %.1f Mpx of map, %.1f s (%.2f Mpx/s, peak %.0f MB); density in %d cells over %.1f %s: %s\n",
              r.output.c_str(), r.detections, model.options().label.c_str(), r.megapixels, r.seconds,
              r.seconds > 0 ? r.megapixels / r.seconds : 0.0, r.peak_rss_mb, r.density_cells, r.total_area,
              r.georeferenced ? "m2 (or px when not in metres)" : "px", r.density_output.c_str());
  return 0;
}

int RunDetect(const DetectSwitches& s) {
  if (!s.frames.empty()) return RunDetectFrames(s);
  if (s.store.empty()) Fail("objects detect", "needs a store (or --frames DIR)");
  if (IsBoxDetectorFile(s.model)) return RunDetectBoxes(s);
  std::string error;
  if (!s.options.IsValid(&error)) Fail("objects detect", error);
  const ObjectModel model = ObjectModel::Load(s.model);
  Progress bar("detect", s.quiet);
  std::mutex mutex;
  const DetectSummary r = DetectObjects(Store::Open(s.store), model, s.options, BarFor(&bar, &mutex));
  bar.Done();
  std::printf("%s: %d detections from %lld windows (%lld without data), %.1f s (%.0f windows/s), %s coordinates\n",
              r.output.c_str(), r.detections, r.windows, r.skipped, r.seconds,
              r.seconds > 0 ? double(r.windows - r.skipped) / r.seconds : 0.0,
              r.georeferenced ? "map" : "pixel");
  return 0;
}

}  // namespace

void AddObjectsCommand(CLI::App& app, Runner* run) {
  auto* cmd = app.add_subcommand("objects", "Identify objects: train a bag-of-words + SVM model, evaluate it, run it over a store");
  cmd->require_subcommand(1);

  auto t = std::make_shared<TrainSwitches>();
  auto* train = cmd->add_subcommand("train", "Train a model from a folder per class");
  auto* data_opt = train->add_option("--data", t->data, "folder with a folder of images per class ('background' = negatives only); repeat to train on several joined");
  train->add_option("--boxes", t->boxes, "folder with images/ and labels_gt/ (YOLO boxes): train a box detector")->excludes(data_opt);
  AddBoxOptions(train, &t->box_options);
  train->add_option("-o,--output", t->output, "model file (.yml.gz)")->required();
  AddClassModelOptions(train, &t->options);
  train->add_flag("-q,--quiet", t->quiet, "no progress bar");
  train->callback([t, run, train] {
    if (t->data.empty() && t->boxes.empty()) throw CLI::RequiredError("--data or --boxes");
    FisherOnlyDefaults(train, &t->options);
    *run = [t] { return RunTrain(*t); };
  });

  auto e = std::make_shared<EvalSwitches>();
  auto* eval = cmd->add_subcommand("eval", "Accuracy, per-class precision/recall and confusion on a held-out split");
  auto* edata = eval->add_option("--data", e->data, "folder with a folder of images per class");
  eval->add_option("--boxes", e->boxes, "folder with images/ and labels_gt/ (YOLO boxes)")->excludes(edata);
  eval->add_option("--model", e->model, "model file from `objects train`");

  eval->add_flag("--json", e->json, "print the figures as JSON");
  eval->add_flag("-q,--quiet", e->quiet, "no progress bar");
  eval->callback([e, run] {
    if (e->data.empty() && e->boxes.empty()) throw CLI::RequiredError("--data or --boxes");
    if (e->model.empty()) throw CLI::RequiredError("--model");
    *run = [e] { return RunEval(*e); };
  });

  auto v = std::make_shared<ValidateSwitches>();
  auto* validate = cmd->add_subcommand("validate", "Cross-validate settings: repeated stratified folds of a folder per class (several folders join), or folds of whole stations of boxed frames");
  auto* vdata = validate->add_option("--data", v->data, "folder with a folder of images per class (repeat to join train and validation)");
  validate->add_option("--boxes", v->boxes, "folder with images/ and labels_gt/ (YOLO boxes): folds of whole stations")->excludes(vdata);
  validate->add_option("--validation-folds", v->folds, "folds (of images per class, or of stations)")->capture_default_str();
  validate->add_option("--repeats", v->repeats, "class model: repeats with another random split")->capture_default_str();
  AddClassModelOptions(validate, &v->options);
  AddBoxOptions(validate, &v->box_options);
  validate->add_flag("--json", v->json, "print the figures as JSON");
  validate->add_flag("-q,--quiet", v->quiet, "no progress bar");
  validate->callback([v, run, validate] {
    if (v->data.empty() && v->boxes.empty()) throw CLI::RequiredError("--data or --boxes");
    FisherOnlyDefaults(validate, &v->options);
    *run = [v] { return RunValidate(*v); };
  });

  auto d = std::make_shared<DetectSwitches>();
  auto* detect = cmd->add_subcommand("detect", "Sliding windows over the mosaic (or a patch): detections as GeoJSON in the store");
  detect->add_option("store", d->store, "the store");
  detect->add_option("--frames", d->frames, "box detector: run over the frames of DIR/images instead, detections as JSON (-o)");
  detect->add_option("--block", d->box_options.block, "box detector: pixels read at a time")->capture_default_str();
  detect->add_option("--density-cell", d->box_options.density_cell,
                     "side of a density cell: metres when georeferenced, pixels otherwise (0 = 512 px)")->capture_default_str();
  detect->add_option("--model", d->model, "model file from `objects train`")->required();
  detect->add_option("--patch", d->options.patch, "patch id (0 = the global mosaic)")->capture_default_str();
  detect->add_option("--level", d->options.level, "pyramid level the windows are cut from")->capture_default_str();
  detect->add_option("--window", d->options.window, "window side, pixels at that level")->capture_default_str();
  detect->add_option("--stride", d->options.stride, "window step, fraction of the window")->capture_default_str();
  detect->add_option("--min-score", d->options.min_score, "SVM decision value a detection needs")->capture_default_str();
  detect->add_option("--nms-iou", d->options.nms_iou, "overlap above which the weaker detection of a class goes")->capture_default_str();
  detect->add_option("--cache-mb", d->options.cache_mb, "tile cache bound, MB")->capture_default_str();
  detect->add_option("-o,--output", d->options.output, "GeoJSON file (default: STORE/objects/detections.geojson)");
  detect->add_flag("-q,--quiet", d->quiet, "no progress bar");
  detect->callback([d, run, detect] {
    // The switches both searches take.
    d->box_options.patch = d->options.patch;
    d->box_options.cache_mb = d->options.cache_mb;
    d->box_options.output = d->options.output;
    if (detect->count("--min-score")) d->box_options.min_score = d->options.min_score;
    *run = [d] { return RunDetect(*d); };
  });
}

}  // namespace rolamos::cli
