#include <cstdio>
#include <mutex>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"
#include "util/progress.h"

namespace rolamos::cli {

namespace {

struct TrainSwitches {
  std::string data, output;
  ObjectTrainOptions options;
  bool quiet = false;
};

struct EvalSwitches {
  std::string data, model;
  bool quiet = false, json = false;
};

struct DetectSwitches {
  std::string store, model;
  DetectOptions options;
  bool quiet = false;
};

// Library progress arrives from worker threads: one bar, redrawn under a lock.
ProgressFn BarFor(Progress* bar, std::mutex* mutex) {
  return [bar, mutex](double fraction) {
    std::lock_guard<std::mutex> lock(*mutex);
    bar->Update(fraction);
  };
}

int RunTrain(const TrainSwitches& s) {
  std::string error;
  if (!s.options.IsValid(&error)) Fail("objects train", error);
  Progress bar("train", s.quiet);
  std::mutex mutex;
  ObjectModel model = ObjectModel::Train(s.data, s.options, BarFor(&bar, &mutex));
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

int RunDetect(const DetectSwitches& s) {
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
  train->add_option("--data", t->data, "folder with a folder of images per class ('background' = negatives only)")->required();
  train->add_option("-o,--output", t->output, "model file (.yml.gz)")->required();
  train->add_option("--vocabulary", t->options.vocabulary, "visual words (k-means)")->capture_default_str();
  train->add_option("--descriptor", t->options.features.descriptor, "sift (gray) or opponent-sift (colour)")
      ->capture_default_str();
  train->add_option("--encoding", t->options.features.encoding, "bow (word histograms), vlad (residuals to the words) or fisher (Fisher vectors: a Gaussian mixture of --vocabulary components)")
      ->capture_default_str();
  train->add_option("--kernel", t->options.kernel, "SVM kernel: chi2, rbf or linear")->capture_default_str();
  train->add_option("--folds", t->options.folds, "cross-validation folds for the SVM parameters")->capture_default_str();
  train->add_option("--image-size", t->options.features.image_size, "samples are resized to this square")->capture_default_str();
  train->add_option("--grid-step", t->options.features.grid_step, "dense SIFT grid step, pixels")->capture_default_str();
  train->add_option("--patch-sizes", t->options.features.patch_sizes, "SIFT support diameters, pixels")
      ->capture_default_str()->delimiter(',');
  train->add_option("--pyramid-levels", t->options.features.pyramid_levels, "spatial pyramid levels (1..3)")->capture_default_str();
  train->add_flag("!--no-centre-cell", t->options.features.centre_cell, "no separate words for the central half");
  train->add_option("--hue-bins", t->options.features.hue_bins, "colour histogram hue bins (0 = no colour)")->capture_default_str();
  train->add_option("--saturation-bins", t->options.features.saturation_bins, "colour histogram saturation bins")->capture_default_str();
  train->add_option("--colour-weight", t->options.features.colour_weight, "weight of colour against words")->capture_default_str();
  train->add_flag("--object-view,!--no-object-view", t->options.features.object_view,
                  "also describe the square around the object found near the centre (on by default)");
  train->add_option("--pca-dims", t->options.features.pca_dims, "descriptor dimensions kept by PCA (fisher)")->capture_default_str();
  train->add_flag("--colour-statistics,!--no-colour-statistics", t->options.features.colour_statistics,
                  "also describe each patch by the mean and spread of its colours (fisher; on by default)");
  train->add_option("--colour-pca-dims", t->options.features.colour_pca_dims, "colour statistics dimensions kept by PCA")
      ->capture_default_str();
  train->add_flag("--spatial-coordinates,!--no-spatial-coordinates", t->options.features.spatial_coordinates,
                  "each descriptor's place joins it in the Gaussian mixture (fisher; on by default)");
  train->add_option("--orientations", t->options.features.orientations,
                    "describe the image in 1, 2 (mirrored), 4 (turned) or 8 orientations, averaged")->capture_default_str();
  train->add_option("--kmeans-samples", t->options.kmeans_samples, "descriptors sampled for k-means")->capture_default_str();
  train->add_option("--seed", t->options.seed, "random seed (sampling, k-means)")->capture_default_str();
  train->add_flag("-q,--quiet", t->quiet, "no progress bar");
  train->callback([t, run, train] {
    // The Fisher-only additions are on by default: with another encoding, they are off unless asked for.
    if (t->options.features.encoding != "fisher") {
      if (train->count("--colour-statistics") + train->count("--no-colour-statistics") == 0) t->options.features.colour_statistics = false;
      if (train->count("--spatial-coordinates") + train->count("--no-spatial-coordinates") == 0) t->options.features.spatial_coordinates = false;
    }
    *run = [t] { return RunTrain(*t); };
  });

  auto e = std::make_shared<EvalSwitches>();
  auto* eval = cmd->add_subcommand("eval", "Accuracy, per-class precision/recall and confusion on a held-out split");
  eval->add_option("--data", e->data, "folder with a folder of images per class")->required();
  eval->add_option("--model", e->model, "model file from `objects train`")->required();
  eval->add_flag("--json", e->json, "print the figures as JSON");
  eval->add_flag("-q,--quiet", e->quiet, "no progress bar");
  eval->callback([e, run] { *run = [e] { return RunEval(*e); }; });

  auto d = std::make_shared<DetectSwitches>();
  auto* detect = cmd->add_subcommand("detect", "Sliding windows over the mosaic (or a patch): detections as GeoJSON in the store");
  detect->add_option("store", d->store, "the store")->required();
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
  detect->callback([d, run] { *run = [d] { return RunDetect(*d); }; });
}

}  // namespace rolamos::cli
