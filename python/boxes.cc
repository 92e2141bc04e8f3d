// Box detection from Python (rolamos objects train/eval/validate/detect with --boxes): a detector
// of one kind of object trained from YOLO-boxed frames, measured by AP50 and station-wise
// validation, run over one image or a store's mosaic.
#include <pybind11/stl.h>

#include "py_common.h"
#include "rolamos/box_detector.hpp"
#include "rolamos/store.hpp"

namespace rolamos::py_bind {

namespace {

const OptionTable<BoxDetectorOptions>& BoxTable() {
  static const OptionTable<BoxDetectorOptions> t = [] {
    using O = BoxDetectorOptions;
    OptionTable<O> t;
    t.Text("label", &O::label).Text("features", &O::features).Number("min_box", &O::min_box)
        .Number("max_box", &O::max_box).Integer("scales_per_octave", &O::scales_per_octave).Number("c", &O::c)
        .Integer("negatives_per_image", &O::negatives_per_image).Integer("hard_negative_rounds", &O::hard_negative_rounds)
        .Integer("hard_negatives_per_image", &O::hard_negatives_per_image).Number("nms_iou", &O::nms_iou).Number("nms_containment", &O::nms_containment)
        .Integer("threads", &O::threads)
        .Custom("seed", [](O& o, const py::handle& v) { o.seed = v.cast<unsigned>(); });
    return t;
  }();
  return t;
}

py::dict EvaluationDict(const BoxEvaluation& e) { return ToPython(ToJson(e)).cast<py::dict>(); }

class PyBoxDetector {
 public:
  explicit PyBoxDetector(BoxDetector d) : d_(std::move(d)) {}
  static PyBoxDetector Load(const py::object& path) { return PyBoxDetector(BoxDetector::Load(FsPath(path))); }
  // Boxes in one image (NumPy RGB, RGBA or gray): [{"bbox": [x, y, w, h], "score": s, "class": label}].
  py::list Detect(const py::handle& image, const py::object& min_score) const {
    const cv::Mat bgr = FromArray(image);
    std::vector<BoxDetection> found;
    {
      py::gil_scoped_release release;
      found = min_score.is_none() ? d_.Detect(bgr) : d_.Detect(bgr, min_score.cast<double>());
    }
    py::list out;
    for (const auto& b : found) {
      py::dict d;
      d["bbox"] = std::vector<double>{b.box.x, b.box.y, b.box.width, b.box.height};
      d["score"] = b.score;
      d["class"] = d_.options().label;
      out.append(d);
    }
    return out;
  }
  double Threshold() const { return d_.threshold(); }
  std::string Label() const { return d_.options().label; }
  py::object Describe() const { return ToPython(d_.Describe()); }
  void Save(const py::object& path) const { d_.Save(FsPath(path)); }
  const BoxDetector& detector() const { return d_; }

 private:
  BoxDetector d_;
};

const BoxDetector& DetectorOf(const py::object& model, std::optional<BoxDetector>* loaded) {
  if (py::isinstance<PyBoxDetector>(model)) return model.cast<const PyBoxDetector&>().detector();
  *loaded = BoxDetector::Load(FsPath(model));
  return **loaded;
}

BoxDetectorOptions Options(const py::kwargs& kwargs, const char* where) {
  BoxDetectorOptions o;
  BoxTable().SetAll(o, kwargs, where);
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  return o;
}

PyBoxDetector Train(const py::object& data, const py::object& output, const py::object& progress, const py::kwargs& kwargs) {
  const BoxDetectorOptions o = Options(kwargs, "objects.train_boxes");
  const std::string dir = FsPath(data), out = output.is_none() ? "" : FsPath(output);
  const ProgressFn report = PythonProgress(progress, "objects.train_boxes");
  InterruptScope interrupt;
  py::gil_scoped_release release;
  BoxDetector d = BoxDetector::Train(ReadBoxedFolder(dir), o, report);
  if (!out.empty()) d.Save(out);
  return PyBoxDetector(std::move(d));
}

py::dict Evaluate(const py::object& data, const py::object& model, const py::object& progress) {
  std::optional<BoxDetector> loaded;
  const BoxDetector& d = DetectorOf(model, &loaded);
  const std::string dir = FsPath(data);
  const ProgressFn report = PythonProgress(progress, "objects.evaluate_boxes");
  InterruptScope interrupt;
  BoxEvaluation e;
  {
    py::gil_scoped_release release;
    e = EvaluateBoxDetector(d, ReadBoxedFolder(dir), report);
  }
  return EvaluationDict(e);
}

py::dict Validate(const py::object& data, int folds, const py::object& progress, const py::kwargs& kwargs) {
  const BoxDetectorOptions o = Options(kwargs, "objects.validate_boxes");
  const std::string dir = FsPath(data);
  const ProgressFn report = PythonProgress(progress, "objects.validate_boxes");
  InterruptScope interrupt;
  BoxValidation v;
  {
    py::gil_scoped_release release;
    v = CrossValidateBoxes(ReadBoxedFolder(dir), o, folds, report);
  }
  return ToPython(ToJson(v)).cast<py::dict>();
}

py::dict DetectInStore(const py::object& store, const py::object& model, const py::object& progress, const py::kwargs& kwargs) {
  BoxSearchOptions o;
  static const OptionTable<BoxSearchOptions> table = [] {
    using O = BoxSearchOptions;
    OptionTable<O> t;
    t.Integer("patch", &O::patch).Number("min_score", &O::min_score).Integer("block", &O::block)
        .Number("max_empty", &O::max_empty).Number("cache_mb", &O::cache_mb).Number("density_cell", &O::density_cell)
        .Integer("threads", &O::threads)
        .Custom("output", [](O& o, const py::handle& v) { o.output = FsPath(v); })
        .Custom("density_output", [](O& o, const py::handle& v) { o.density_output = FsPath(v); });
    return t;
  }();
  table.SetAll(o, kwargs, "objects.detect");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  std::optional<BoxDetector> loaded;
  const BoxDetector& d = DetectorOf(model, &loaded);
  const std::string dir = FsPath(store);
  const ProgressFn report = PythonProgress(progress, "objects.detect");
  InterruptScope interrupt;
  BoxSearchSummary r;
  {
    py::gil_scoped_release release;
    r = DetectBoxesInStore(Store::Open(dir), d, o, report);
  }
  py::dict out;
  out["detections"] = r.detections;
  out["megapixels"] = r.megapixels;
  out["seconds"] = r.seconds;
  out["output"] = r.output;
  out["density_output"] = r.density_output;
  out["georeferenced"] = r.georeferenced;
  return out;
}

}  // namespace

void BindBoxes(py::module_& m) {
  py::class_<PyBoxDetector>(m, "BoxDetector", "A detector of one kind of object by its box (rolamos objects train --boxes).")
      .def_static("load", &PyBoxDetector::Load, py::arg("path"), "Loads a box detector file (.yml.gz).")
      .def_property_readonly("threshold", &PyBoxDetector::Threshold, "its operating score (the best F1 in training)")
      .def_property_readonly("label", &PyBoxDetector::Label, "the class it reports")
      .def("describe", &PyBoxDetector::Describe, "settings and training figures")
      .def("detect", &PyBoxDetector::Detect, py::arg("image"), py::arg("min_score") = py::none(),
           "Boxes in one image (NumPy uint8/uint16, RGB, RGBA or gray): [{'bbox': [x, y, w, h], 'score', 'class'}], "
           "best first; min_score defaults to its threshold.")
      .def("save", &PyBoxDetector::Save, py::arg("path"), "Writes the detector (.yml.gz or .yml).");
  m.def("is_box_detector", [](const py::object& path) { return IsBoxDetectorFile(FsPath(path)); }, py::arg("path"),
        "True when the file holds a box detector (not a class model).");
  m.def("objects_train_boxes", &Train, py::arg("data"), py::arg("output") = py::none(), py::kw_only(),
        py::arg("progress") = py::none(),
        "Trains a box detector from DATA/images and DATA/labels_gt (YOLO) and saves it to `output` when given. "
        "Options as `rolamos objects train --boxes`: label, features, min_box, max_box, c, hard_negative_rounds, ...");
  m.def("objects_evaluate_boxes", &Evaluate, py::arg("data"), py::arg("model"), py::kw_only(),
        py::arg("progress") = py::none(), "AP50, precision, recall and F1 of a box detector on boxed frames.");
  m.def("objects_validate_boxes", &Validate, py::arg("data"), py::arg("folds") = 3, py::kw_only(),
        py::arg("progress") = py::none(),
        "Station-wise cross-validation of a box detector's settings: pooled and per-fold AP50, precision, recall.");
  m.def("objects_detect_boxes", &DetectInStore, py::arg("store"), py::arg("model"), py::kw_only(),
        py::arg("progress") = py::none(),
        "A box detector over the store's mosaic (patch=N: a patch) in blocks through the tile cache; writes the "
        "detections and the density layer (objects/density.geojson).");
}

}  // namespace rolamos::py_bind
