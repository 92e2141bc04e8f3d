// Object identification from Python (rolamos objects): a model trained from a folder per class,
// evaluated on another, run over a store's mosaic or a patch, or asked about one image.
#include <pybind11/stl.h>

#include "py_common.h"
#include "rolamos/objects.hpp"
#include "rolamos/store.hpp"

namespace rolamos::py_bind {

namespace {

// `objects train`'s switches, by the same names.
const OptionTable<ObjectTrainOptions>& TrainTable() {
  static const OptionTable<ObjectTrainOptions> t = [] {
    using O = ObjectTrainOptions;
    OptionTable<O> t;
    t.Integer("vocabulary", &O::vocabulary).Text("kernel", &O::kernel).Integer("folds", &O::folds)
        .Integer("kmeans_samples", &O::kmeans_samples).Text("select_by", &O::select_by)
        .Custom("seed", [](O& o, const py::handle& v) { o.seed = v.cast<unsigned>(); })
        .Custom("descriptor", [](O& o, const py::handle& v) { o.features.descriptor = v.cast<std::string>(); })
        .Custom("encoding", [](O& o, const py::handle& v) { o.features.encoding = v.cast<std::string>(); })
        .Custom("image_size", [](O& o, const py::handle& v) { o.features.image_size = v.cast<int>(); })
        .Custom("grid_step", [](O& o, const py::handle& v) { o.features.grid_step = v.cast<int>(); })
        .Custom("patch_sizes", [](O& o, const py::handle& v) { o.features.patch_sizes = v.cast<std::vector<int>>(); })
        .Custom("pyramid_levels", [](O& o, const py::handle& v) { o.features.pyramid_levels = v.cast<int>(); })
        .Custom("centre_cell", [](O& o, const py::handle& v) { o.features.centre_cell = v.cast<bool>(); })
        .Custom("hue_bins", [](O& o, const py::handle& v) { o.features.hue_bins = v.cast<int>(); })
        .Custom("saturation_bins", [](O& o, const py::handle& v) { o.features.saturation_bins = v.cast<int>(); })
        .Custom("colour_weight", [](O& o, const py::handle& v) { o.features.colour_weight = v.cast<double>(); })
        .Custom("object_view", [](O& o, const py::handle& v) { o.features.object_view = v.cast<bool>(); })
        .Custom("pca_dims", [](O& o, const py::handle& v) { o.features.pca_dims = v.cast<int>(); })
        .Custom("colour_statistics", [](O& o, const py::handle& v) { o.features.colour_statistics = v.cast<bool>(); })
        .Custom("colour_pca_dims", [](O& o, const py::handle& v) { o.features.colour_pca_dims = v.cast<int>(); })
        .Custom("spatial_coordinates",
                [](O& o, const py::handle& v) { o.features.spatial_coordinates = v.cast<bool>(); })
        .Custom("orientations", [](O& o, const py::handle& v) { o.features.orientations = v.cast<int>(); });
    return t;
  }();
  return t;
}

// As the CLI: the Fisher-only additions are off for another encoding unless asked for.
void FisherOnlyDefaults(ObjectTrainOptions* o, const py::kwargs& kwargs) {
  if (o->features.encoding == "fisher") return;
  if (!kwargs.contains("colour_statistics")) o->features.colour_statistics = false;
  if (!kwargs.contains("spatial_coordinates")) o->features.spatial_coordinates = false;
}

// A trained model, loaded once and asked many times.
class PyObjectModel {
 public:
  explicit PyObjectModel(ObjectModel model) : model_(std::move(model)) {}
  static PyObjectModel Load(const py::object& path) { return PyObjectModel(ObjectModel::Load(FsPath(path))); }
  std::vector<std::string> Classes() const { return model_.classes(); }
  py::object Describe() const { return ToPython(model_.Describe()); }
  // Every class's score for one image, best first.
  std::vector<std::pair<std::string, double>> Classify(const py::handle& image) const {
    const cv::Mat bgr = FromArray(image);
    std::vector<ClassScore> scores;
    {
      py::gil_scoped_release release;
      scores = model_.Classify(bgr);
    }
    std::vector<std::pair<std::string, double>> out;
    for (const auto& s : scores) out.emplace_back(s.label, s.score);
    return out;
  }
  void Save(const py::object& path) const { model_.Save(FsPath(path)); }
  const ObjectModel& model() const { return model_; }

 private:
  ObjectModel model_;
};

PyObjectModel Train(const py::object& data, const py::object& output, const py::object& progress,
                    const py::kwargs& kwargs) {
  ObjectTrainOptions o;
  TrainTable().SetAll(o, kwargs, "objects.train");
  FisherOnlyDefaults(&o, kwargs);
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  const std::string dir = FsPath(data);
  const std::string out = output.is_none() ? "" : FsPath(output);
  const ProgressFn report = PythonProgress(progress, "objects.train");
  InterruptScope interrupt;
  py::gil_scoped_release release;
  ObjectModel model = ObjectModel::Train(dir, o, report);
  if (!out.empty()) model.Save(out);
  return PyObjectModel(std::move(model));
}

const ObjectModel& ModelOf(const py::object& model, std::optional<ObjectModel>* loaded) {
  if (py::isinstance<PyObjectModel>(model)) return model.cast<const PyObjectModel&>().model();
  *loaded = ObjectModel::Load(FsPath(model));
  return **loaded;
}

py::dict Evaluate(const py::object& data, const py::object& model, const py::object& progress) {
  std::optional<ObjectModel> loaded;
  const ObjectModel& m = ModelOf(model, &loaded);
  const std::string dir = FsPath(data);
  const ProgressFn report = PythonProgress(progress, "objects.evaluate");
  InterruptScope interrupt;
  ObjectEvaluation e;
  {
    py::gil_scoped_release release;
    e = EvaluateObjects(m, dir, report);
  }
  py::dict d;
  d["accuracy"] = e.accuracy;
  d["images"] = e.images;
  d["classes"] = e.classes;
  d["precision"] = e.precision;
  d["recall"] = e.recall;
  d["support"] = e.support;
  d["confusion"] = e.confusion;
  d["seconds"] = e.seconds;
  return d;
}

py::dict Validate(const std::vector<py::object>& data, int folds, int repeats, const py::object& progress,
                  const py::kwargs& kwargs) {
  ObjectTrainOptions o;
  TrainTable().SetAll(o, kwargs, "objects.validate");
  FisherOnlyDefaults(&o, kwargs);
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  if (folds < 2 || repeats < 1) throw py::value_error("folds must be 2 or more and repeats 1 or more");
  std::vector<std::string> dirs;
  for (const auto& d : data) dirs.push_back(FsPath(d));
  const ProgressFn report = PythonProgress(progress, "objects.validate");
  InterruptScope interrupt;
  ObjectValidation v;
  {
    py::gil_scoped_release release;
    v = CrossValidateObjects(ReadLabelledFolders(dirs), o, folds, repeats, report);
  }
  return ToPython(ToJson(v)).cast<py::dict>();
}

py::dict Detect(const py::object& store, const py::object& model, const py::object& progress, const py::kwargs& kwargs) {
  DetectOptions o;
  static const OptionTable<DetectOptions> table = [] {
    OptionTable<DetectOptions> t;
    t.Integer("patch", &DetectOptions::patch).Integer("level", &DetectOptions::level)
        .Integer("window", &DetectOptions::window).Number("stride", &DetectOptions::stride)
        .Number("min_score", &DetectOptions::min_score).Number("nms_iou", &DetectOptions::nms_iou)
        .Number("max_empty", &DetectOptions::max_empty).Number("cache_mb", &DetectOptions::cache_mb)
        .Custom("output", [](DetectOptions& o, const py::handle& v) { o.output = FsPath(v); });
    return t;
  }();
  table.SetAll(o, kwargs, "objects.detect");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  std::optional<ObjectModel> loaded;
  const ObjectModel& m = ModelOf(model, &loaded);
  const std::string dir = FsPath(store);
  const ProgressFn report = PythonProgress(progress, "objects.detect");
  InterruptScope interrupt;
  DetectSummary r;
  {
    py::gil_scoped_release release;
    r = DetectObjects(Store::Open(dir), m, o, report);
  }
  py::dict d;
  d["detections"] = r.detections;
  d["windows"] = r.windows;
  d["skipped"] = r.skipped;
  d["seconds"] = r.seconds;
  d["output"] = r.output;
  d["georeferenced"] = r.georeferenced;
  return d;
}

}  // namespace

void BindObjects(py::module_& m) {
  py::class_<PyObjectModel>(m, "ObjectModel", "A trained object model (rolamos objects train).")
      .def_static("load", &PyObjectModel::Load, py::arg("path"), "Loads a model file (.yml.gz).")
      .def_property_readonly("classes", &PyObjectModel::Classes, "the classes it reports (not the background)")
      .def("describe", &PyObjectModel::Describe, "settings, classes, training counts and SVM parameters")
      .def("classify", &PyObjectModel::Classify, py::arg("image"),
           "Every class's score for one image (uint8 array (h, w, 3) RGB): [(label, score)], best first; a "
           "score > 0 means this class rather than the others.")
      .def("save", &PyObjectModel::Save, py::arg("path"), "Writes the model (.yml.gz or .yml).");
  m.def("objects_train", &Train, py::arg("data"), py::arg("output") = py::none(), py::kw_only(),
        py::arg("progress") = py::none(),
        "Trains a model from a folder of images per class ('background': negatives only) and saves it to "
        "`output` when given. Options as `rolamos objects train`'s switches.");
  m.def("objects_evaluate", &Evaluate, py::arg("data"), py::arg("model"), py::kw_only(),
        py::arg("progress") = py::none(),
        "Accuracy, per-class precision and recall and the confusion matrix on a folder per class.");
  m.def("objects_validate", &Validate, py::arg("data"), py::arg("folds") = 5, py::arg("repeats") = 1, py::kw_only(),
        py::arg("progress") = py::none(),
        "Repeated stratified cross-validation of the training options over the folders joined (a folder per "
        "class each): accuracy mean and spread over folds, pooled per-class recall and confusion.");
  m.def("objects_detect", &Detect, py::arg("store"), py::arg("model"), py::kw_only(), py::arg("progress") = py::none(),
        "Sliding windows over the mosaic (or patch=N) through the tile cache; detections as GeoJSON in the "
        "store (objects/detections.geojson, or output=PATH). Options: patch, level, window, stride, min_score, "
        "nms_iou, max_empty, cache_mb, output.");
}

}  // namespace rolamos::py_bind
