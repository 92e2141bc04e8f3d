// The rolamos Python module's native part (`rolamos._rolamos`): pybind11 bindings of the library
// the CLI calls. Pixels cross as NumPy arrays (h, w, channels) in RGB(A) order; library errors
// become rolamos.Error with the library's message; long calls release the GIL.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <functional>
#include <map>
#include <memory>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/describe.hpp"
#include "rolamos/global_align.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/store.hpp"
#include "rolamos/tile_cache.hpp"
#include "rolamos/tiled_image.hpp"

namespace py = pybind11;

namespace rolamos {
namespace {

// JSON into Python objects, through the json module (exact types, nested).
py::object ToPython(const nlohmann::json& j) { return py::module_::import("json").attr("loads")(j.dump()); }

// OpenCV's BGR(A)/gray Mat -> a NumPy array (h, w, c) in RGB(A) order, owning its copy.
py::array ToArray(cv::Mat m) {
  if (m.channels() == 3) cv::cvtColor(m, m, cv::COLOR_BGR2RGB);
  else if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2RGBA);
  if (!m.isContinuous()) m = m.clone();
  const std::vector<py::ssize_t> shape = {m.rows, m.cols, m.channels()};
  auto* keep = new cv::Mat(m);
  py::capsule owner(keep, [](void* p) { delete static_cast<cv::Mat*>(p); });
  if (m.depth() == CV_16U) return py::array_t<uint16_t>(shape, reinterpret_cast<const uint16_t*>(keep->data), owner);
  return py::array_t<uint8_t>(shape, keep->data, owner);
}

// A NumPy frame (h, w, 3) RGB or (h, w) gray, uint8 -> BGR Mat (a copy).
cv::Mat FromArray(const py::array& a) {
  const auto frame = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>::ensure(a);
  if (!frame) throw py::value_error("frame: expected a NumPy array of uint8");
  if (frame.ndim() == 2) {
    cv::Mat gray(static_cast<int>(frame.shape(0)), static_cast<int>(frame.shape(1)), CV_8UC1,
                 const_cast<uint8_t*>(frame.data()));
    cv::Mat bgr;
    cv::cvtColor(gray, bgr, cv::COLOR_GRAY2BGR);
    return bgr;
  }
  if (frame.ndim() != 3 || (frame.shape(2) != 3 && frame.shape(2) != 4))
    throw py::value_error("frame: expected shape (h, w, 3) RGB, (h, w, 4) RGBA or (h, w) gray");
  cv::Mat rgb(static_cast<int>(frame.shape(0)), static_cast<int>(frame.shape(1)), CV_8UC(static_cast<int>(frame.shape(2))),
              const_cast<uint8_t*>(frame.data()));
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, frame.shape(2) == 3 ? cv::COLOR_RGB2BGR : cv::COLOR_RGBA2BGR);
  return bgr;
}

// An image of a store (the mosaic or a patch) or any tiled TIFF, read through the tile cache.
class Image {
 public:
  Image(const std::string& path, double cache_mb) {
    TileCacheOptions o;
    o.max_memory_mb = cache_mb;
    std::string error;
    if (!o.IsValid(&error)) throw py::value_error("cache_mb: " + error);
    image_ = std::make_shared<TiledImage>(TiledImage::Open(path, std::make_shared<TileCache>(o)));
  }
  long long width() const { return image_->width(); }
  long long height() const { return image_->height(); }
  int levels() const { return image_->num_levels(); }
  int channels() const { return image_->info().channels; }
  std::string dtype() const { return image_->info().bits == 16 ? "uint16" : "uint8"; }
  std::string path() const { return image_->info().path; }
  py::list level_sizes() const {
    py::list out;
    for (const auto& l : image_->info().levels) out.append(py::make_tuple(l.width, l.height));
    return out;
  }
  py::array Read(long long x, long long y, long long w, long long h, int level, std::optional<double> scale) const {
    if (w <= 0 || h <= 0) throw py::value_error("w and h must be positive");
    cv::Mat m;
    if (scale) {
      if (!(*scale > 0 && *scale <= 1)) throw py::value_error("scale must be in (0, 1]");
      if (level != 0) throw py::value_error("give level or scale, not both");
      py::gil_scoped_release release;
      m = image_->ReadScaled(cv::Rect(static_cast<int>(x), static_cast<int>(y), static_cast<int>(w), static_cast<int>(h)), *scale);
    } else {
      if (level < 0 || level >= levels()) throw py::value_error("level " + std::to_string(level) + " is outside 0.." + std::to_string(levels() - 1));
      py::gil_scoped_release release;
      m = image_->ReadRegion(level, cv::Rect(static_cast<int>(x), static_cast<int>(y), static_cast<int>(w), static_cast<int>(h)));
    }
    return ToArray(m);
  }

 private:
  std::shared_ptr<TiledImage> image_;
};

// Options by the CLI's names (dashes or underscores), each checked for its type; unknown names and
// values the library refuses raise ValueError naming the option.
void SetOption(MosaickerOptions& o, std::string name, const py::handle& v) {
  for (char& c : name)
    if (c == '-') c = '_';
  using Setter = std::function<void(MosaickerOptions&, const py::handle&)>;
  auto num = [](double MosaickerOptions::*f) -> Setter { return [f](MosaickerOptions& o, const py::handle& v) { o.*f = v.cast<double>(); }; };
  auto integer = [](int MosaickerOptions::*f) -> Setter { return [f](MosaickerOptions& o, const py::handle& v) { o.*f = v.cast<int>(); }; };
  auto flag = [](bool MosaickerOptions::*f) -> Setter { return [f](MosaickerOptions& o, const py::handle& v) { o.*f = v.cast<bool>(); }; };
  auto text = [](std::string MosaickerOptions::*f) -> Setter { return [f](MosaickerOptions& o, const py::handle& v) { o.*f = v.cast<std::string>(); }; };
  static const std::map<std::string, Setter> setters = {
      {"calibration", text(&MosaickerOptions::calibration)}, {"fov", num(&MosaickerOptions::fov_deg)},
      {"mask", text(&MosaickerOptions::mask)}, {"bilateral", flag(&MosaickerOptions::bilateral)},
      {"temporal", flag(&MosaickerOptions::temporal)}, {"clahe", flag(&MosaickerOptions::clahe)},
      {"track_pixels", num(&MosaickerOptions::track_pixels)}, {"track_points", integer(&MosaickerOptions::track_points)},
      {"keyframe_overlap", num(&MosaickerOptions::keyframe_overlap)},
      {"keyframe_min_overlap", num(&MosaickerOptions::keyframe_min_overlap)},
      {"describe_overlap", num(&MosaickerOptions::describe_overlap)},
      {"features", text(&MosaickerOptions::features)}, {"max_features", integer(&MosaickerOptions::max_features)},
      {"detect_scale", num(&MosaickerOptions::detect_scale)}, {"sift_upsample", flag(&MosaickerOptions::sift_upsample)},
      {"ratio", num(&MosaickerOptions::ratio)}, {"cross_check", flag(&MosaickerOptions::cross_check)},
      {"fundamental", flag(&MosaickerOptions::fundamental)},
      {"epipolar_threshold", num(&MosaickerOptions::epipolar_threshold)},
      {"homography_threshold", num(&MosaickerOptions::homography_threshold)},
      {"min_inliers", integer(&MosaickerOptions::min_inliers)}, {"kalman", flag(&MosaickerOptions::kalman)},
      {"recover", flag(&MosaickerOptions::recover)}, {"patch_fit", flag(&MosaickerOptions::patch_fit)},
      {"adjust", flag(&MosaickerOptions::adjust_patches)}, {"patch_frames_mb", num(&MosaickerOptions::patch_frames_mb)},
      {"ecc", flag(&MosaickerOptions::ecc)}, {"ecc_scale", num(&MosaickerOptions::ecc_scale)},
      {"ecc_motion", text(&MosaickerOptions::ecc_motion)}, {"feather_sigma", num(&MosaickerOptions::feather_sigma)},
      {"flat_field", flag(&MosaickerOptions::flat_field)}, {"exposure", flag(&MosaickerOptions::exposure)},
      {"water_colour", flag(&MosaickerOptions::water_colour)},
      {"patch_megapixels", num(&MosaickerOptions::patch_megapixels)},
      {"max_lost_frames", integer(&MosaickerOptions::max_lost_frames)},
      {"checkpoint_frames", integer(&MosaickerOptions::checkpoint_frames)},
  };
  auto it = setters.find(name);
  if (it == setters.end()) throw py::value_error("unknown option '" + name + "' (see help(rolamos.Mosaicker))");
  try {
    it->second(o, v);
  } catch (const py::cast_error&) {
    throw py::value_error("option '" + name + "': wrong type (" + std::string(py::str(v.get_type())) + ")");
  }
}

MosaickerOptions ToOptions(const py::kwargs& kwargs) {
  MosaickerOptions o;
  o.mask = "";  // frames pushed one by one: no first frames to search an overlay in beforehand
  for (const auto& [k, v] : kwargs) SetOption(o, k.cast<std::string>(), v);
  if (o.mask == "none") o.mask.clear();
  if (o.mask == "auto")
    throw py::value_error("option 'mask': 'auto' searches the first frames of a folder or video (rolamos.mosaic); "
                          "frames pushed one by one need a mask file or 'none'");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  return o;
}

// A library progress callback for a long call made without the GIL: it takes the GIL, calls the
// user's `progress(fraction, message)` (when given) and honours Ctrl-C (KeyboardInterrupt), by
// throwing out of the library call (its writes are atomic: nothing half-written stays).
ProgressFn PythonProgress(const py::object& progress, const std::string& message) {
  return [progress, message](double fraction) {
    py::gil_scoped_acquire acquire;
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (!progress.is_none()) progress(fraction, message);
  };
}

py::dict Compose(const std::string& store, long long max_pixels, int bands, bool exposure, bool restart,
                 const py::object& progress) {
  ComposeOptions o;
  o.max_pixels = max_pixels;
  o.bands = bands;
  o.exposure = exposure;
  o.restart = restart;
  // The CLI's defaults (rolamos compose): WebP at quality 90 in 256-pixel tiles.
  o.tiff.compression = Compression::kWebp;
  o.tiff.quality = 90;
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  ComposeResult r;
  {
    py::gil_scoped_release release;
    r = ComposeMosaic(Store::Open(store), o, PythonProgress(progress, "compose"));
  }
  py::dict d;
  d["width"] = r.width;
  d["height"] = r.height;
  d["scale"] = r.scale;
  d["patches_used"] = r.patches_used;
  py::list left;
  for (const auto& [id, why] : r.left_out) left.append(py::make_tuple(id, why));
  d["left_out"] = left;
  return d;
}

py::dict Align(const std::string& store, const py::object& progress) {
  AlignOptions o;
  AlignSummary r;
  {
    py::gil_scoped_release release;
    r = AlignStore(Store::Open(store), o, PythonProgress(progress, "align"));
  }
  py::dict d;
  d["frames"] = r.frames;
  d["components"] = r.components;
  d["component_frames"] = r.component_frames;
  d["edges_dropped"] = r.edges_dropped;
  d["rms_before_px"] = r.rms_before_px;
  d["rms_after_px"] = r.rms_after_px;
  d["seconds"] = r.seconds;
  return d;
}

py::dict Export(const std::string& image_path, const std::string& output, std::optional<std::vector<double>> region,
                int level, double scale, const py::object& progress) {
  ExportOptions o;
  o.output = output;
  o.level = level;
  o.scale = scale;
  if (region) {
    if (region->size() != 4) throw py::value_error("region: expected (x, y, w, h)");
    o.region = cv::Rect2d((*region)[0], (*region)[1], (*region)[2], (*region)[3]);
  }
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  ExportResult r;
  {
    py::gil_scoped_release release;
    const TiledImage image = TiledImage::Open(image_path);
    r = ExportRegion(image, o, PythonProgress(progress, "export"));
  }
  py::dict d;
  d["width"] = r.width;
  d["height"] = r.height;
  d["level"] = r.level;
  d["scale"] = r.scale;
  return d;
}

py::dict ReportDict(const FrameReport& r) {
  py::dict d;
  d["index"] = r.index;
  d["status"] = r.status;
  d["reason"] = r.reason;
  d["note"] = r.note;
  d["patch_id"] = r.patch_id;
  d["started_patch"] = r.started_patch;
  d["keyframe"] = r.keyframe;
  d["matches"] = r.matches;
  d["inliers"] = r.inliers;
  d["bilateral_error"] = r.bilateral_error;
  d["ecc"] = r.ecc;
  return d;
}

// Frames pushed one at a time (a camera SDK, a ROS bag), as `rolamos mosaic` does with a folder.
class PyMosaicker {
 public:
  PyMosaicker(const std::string& store, const py::kwargs& kwargs) {
    const MosaickerOptions o = ToOptions(kwargs);
    Store s = Store::LooksLikeStore(store) ? Store::Open(store) : Store::Create(store, StoreOptions{});
    mosaicker_ = std::make_unique<Mosaicker>(s, o);
  }
  py::dict Push(const py::array& frame, std::optional<std::string> name) {
    if (!mosaicker_) Fail("Mosaicker", "closed: no more frames can be pushed");
    const cv::Mat bgr = FromArray(frame);
    const std::string source = name ? *name : "frame_" + std::to_string(pushed_);
    ++pushed_;
    FrameReport r;
    {
      py::gil_scoped_release release;
      r = mosaicker_->Push(bgr, source);
    }
    return ReportDict(r);
  }
  py::dict Close() {
    if (!mosaicker_) Fail("Mosaicker", "already closed");
    MosaicSummary s;
    {
      py::gil_scoped_release release;
      s = mosaicker_->Finish();
    }
    mosaicker_.reset();
    py::dict d;
    d["frames"] = s.frames;
    d["stitched"] = s.stitched;
    d["rejected"] = s.rejected;
    d["patches"] = s.patches;
    d["keyframes"] = s.keyframes;
    d["seconds"] = s.seconds;
    return d;
  }

 private:
  std::unique_ptr<Mosaicker> mosaicker_;
  long pushed_ = 0;
};

}  // namespace
}  // namespace rolamos

PYBIND11_MODULE(_rolamos, m) {
  using namespace rolamos;
  m.doc() = "rolamos native bindings (use the rolamos package)";
  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const Error& e) {
      error(e.what());
    }
  });

  py::class_<Image>(m, "Image", "A tiled image (mosaic, patch or any tiled TIFF) read through a bounded tile cache.")
      .def(py::init<const std::string&, double>(), py::arg("path"), py::arg("cache_mb") = 256.0)
      .def_property_readonly("width", &Image::width, "level-0 width in pixels")
      .def_property_readonly("height", &Image::height, "level-0 height in pixels")
      .def_property_readonly("levels", &Image::levels, "number of pyramid levels")
      .def_property_readonly("channels", &Image::channels, "1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA)")
      .def_property_readonly("dtype", &Image::dtype, "'uint8' or 'uint16'")
      .def_property_readonly("path", &Image::path)
      .def_property_readonly("level_sizes", &Image::level_sizes, "(width, height) of every level")
      .def("read", &Image::Read, py::arg("x"), py::arg("y"), py::arg("w"), py::arg("h"), py::arg("level") = 0,
           py::arg("scale") = py::none(),
           "Pixels of a rectangle: at `level` in that level's coordinates, or with `scale` (0 < s <= 1) the "
           "level-0 rectangle resampled. Returns an array (h, w, channels) in RGB(A) order.");

  py::class_<PyMosaicker>(m, "Mosaicker", "The online engine: push frames, then close().")
      .def(py::init<const std::string&, const py::kwargs&>(), py::arg("store"))
      .def("push", &PyMosaicker::Push, py::arg("frame"), py::arg("name") = py::none(),
           "Maps one frame (uint8 array (h, w, 3) RGB or (h, w) gray); returns the frame's report.")
      .def("close", &PyMosaicker::Close, "Writes the last patch; returns the run's totals.");

  m.def("compose", &Compose, py::arg("store"), py::kw_only(), py::arg("max_pixels") = 0, py::arg("bands") = 0,
        py::arg("exposure") = true, py::arg("restart") = false, py::arg("progress") = py::none(),
        "Composes the store's patches into mosaic.tif (rolamos compose). `progress(fraction, message)` is "
        "called as it goes; Ctrl-C interrupts it (a later compose resumes).");
  m.def("align", &Align, py::arg("store"), py::kw_only(), py::arg("progress") = py::none(),
        "The global map over every frame (rolamos align); compose draws it.");
  m.def("export", &Export, py::arg("image"), py::arg("output"), py::kw_only(), py::arg("region") = py::none(),
        py::arg("level") = -1, py::arg("scale") = 1.0, py::arg("progress") = py::none(),
        "A region (x, y, w, h in level-0 pixels) of a tiled image to .tif (streamed), .png or .jpg.");
  m.def("describe_store", [](const std::string& dir) { return ToPython(DescribeStore(dir)); }, py::arg("path"),
        "What `rolamos info --json` prints for a store.");
  m.def("describe_image", [](const std::string& path) { return ToPython(DescribeImage(path)); }, py::arg("path"),
        "What `rolamos info --json` prints for an image file.");
}
