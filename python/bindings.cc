// The rolamos Python module's native part (`rolamos._rolamos`): pybind11 bindings of the library
// the CLI calls. Pixels cross as NumPy arrays (h, w, channels) in RGB(A) order; library errors
// become rolamos.Error with the library's message; long calls release the GIL.
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

#include "py_common.h"

#include <signal.h>

#include <atomic>

namespace rolamos::py_bind {

py::object ToPython(const nlohmann::json& j) { return py::module_::import("json").attr("loads")(j.dump()); }

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

cv::Mat FromArray(const py::handle& handle) {
  if (!py::isinstance<py::array>(handle))
    throw py::value_error("frame: expected a NumPy array, not " + std::string(py::str(handle.get_type())));
  const py::array a = py::reinterpret_borrow<py::array>(handle);
  const std::string dtype = py::str(a.dtype());
  const bool deep = a.dtype().is(py::dtype::of<uint16_t>());
  if (!a.dtype().is(py::dtype::of<uint8_t>()) && !deep)
    throw py::value_error("frame: dtype " + dtype + " is not uint8 or uint16");
  const bool gray = a.ndim() == 2, colour = a.ndim() == 3 && (a.shape(2) == 3 || a.shape(2) == 4);
  if (!gray && !colour) {
    std::string shape;
    for (py::ssize_t i = 0; i < a.ndim(); ++i) shape += (i ? ", " : "") + std::to_string(a.shape(i));
    throw py::value_error("frame: shape (" + shape + ") is not (h, w, 3) RGB, (h, w, 4) RGBA or (h, w) gray");
  }
  if (a.shape(0) < 16 || a.shape(1) < 16)
    throw py::value_error("frame: " + std::to_string(a.shape(1)) + " x " + std::to_string(a.shape(0)) +
                          " pixels is too small to map");
  const int channels = gray ? 1 : static_cast<int>(a.shape(2));
  // A C-contiguous copy of whatever layout came in (views, slices, Fortran order).
  const py::array c = py::module_::import("numpy").attr("ascontiguousarray")(a);
  const cv::Mat in(static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)),
                   CV_MAKETYPE(deep ? CV_16U : CV_8U, channels), const_cast<void*>(c.data()));
  cv::Mat bgr;
  if (channels == 1) cv::cvtColor(in, bgr, cv::COLOR_GRAY2BGR);
  else cv::cvtColor(in, bgr, channels == 3 ? cv::COLOR_RGB2BGR : cv::COLOR_RGBA2BGR);
  return bgr;
}

namespace {
std::atomic<bool> g_interrupted{false};
struct sigaction g_python_sigint;
void OnSigint(int) { g_interrupted = true; }
}  // namespace

const std::atomic<bool>* InterruptFlag() { return &g_interrupted; }

InterruptScope::InterruptScope() {
  const py::module_ threading = py::module_::import("threading");
  if (!threading.attr("current_thread")().is(threading.attr("main_thread")())) return;
  g_interrupted = false;
  struct sigaction sa {};
  sa.sa_handler = OnSigint;
  sigemptyset(&sa.sa_mask);
  installed_ = sigaction(SIGINT, &sa, &g_python_sigint) == 0;
}

InterruptScope::~InterruptScope() {
  if (installed_) sigaction(SIGINT, &g_python_sigint, nullptr);
}

ProgressFn PythonProgress(const py::object& progress, const std::string& message) {
  // The callable is shared by the callback's copies (made on any thread, without the GIL) and
  // released under the GIL.
  std::shared_ptr<py::object> callable;
  if (!progress.is_none())
    callable.reset(new py::object(progress), [](py::object* o) {
      py::gil_scoped_acquire acquire;
      delete o;
    });
  return [callable, message](double fraction) {
    if (g_interrupted) throw Interrupted();
    if (!callable) return;
    py::gil_scoped_acquire acquire;
    (*callable)(fraction, message);
  };
}

namespace {

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
    if (w <= 0 || h <= 0)
      throw py::value_error("window " + std::to_string(w) + " x " + std::to_string(h) + ": w and h must be positive");
    if (scale && level != 0) throw py::value_error("give level or scale, not both");
    if (scale && !(*scale > 0 && *scale <= 1)) throw py::value_error("scale " + std::to_string(*scale) + " is not in (0, 1]");
    if (!scale && (level < 0 || level >= levels()))
      throw py::value_error("level " + std::to_string(level) + " is outside 0.." + std::to_string(levels() - 1));
    // The window must lie inside the level it reads (level 0 with a scale).
    const auto& l = image_->info().levels[size_t(scale ? 0 : level)];
    if (x < 0 || y < 0 || x + w > l.width || y + h > l.height)
      throw py::value_error("window (" + std::to_string(x) + ", " + std::to_string(y) + ", " + std::to_string(w) + ", " +
                            std::to_string(h) + ") leaves level " + std::to_string(scale ? 0 : level) + " of " +
                            image_->info().path + " (" + std::to_string(l.width) + " x " + std::to_string(l.height) + ")");
    const cv::Rect r(static_cast<int>(x), static_cast<int>(y), static_cast<int>(w), static_cast<int>(h));
    if (scale) {
      cv::Mat m;
      {
        py::gil_scoped_release release;
        m = image_->ReadScaled(r, *scale);
      }
      return ToArray(m);
    }
    // Straight into the array NumPy owns, in the file's RGB(A) order: no copy, no channel swap.
    // (Reading bands of tile rows on several threads gains nothing: OpenImageIO's cache decodes
    // the tiles of one file one at a time.)
    const bool deep = image_->info().bits == 16;
    const std::vector<py::ssize_t> shape = {h, w, channels()};
    py::array out = deep ? py::array(py::array_t<uint16_t>(shape)) : py::array(py::array_t<uint8_t>(shape));
    cv::Mat dst(r.height, r.width, image_->cv_type(), out.mutable_data());
    {
      py::gil_scoped_release release;
      image_->ReadRegionInto(level, r, dst, /*file_order=*/true);
    }
    return out;
  }

 private:
  std::shared_ptr<TiledImage> image_;
};

// The engine's options by the CLI's names (mosaic --help), validated by MosaickerOptions::IsValid.
const OptionTable<MosaickerOptions>& MosaickerTable() {
  static const OptionTable<MosaickerOptions> t = [] {
    using O = MosaickerOptions;
    OptionTable<O> t;
    t.Text("calibration", &O::calibration).Number("fov", &O::fov_deg).Text("mask", &O::mask)
        .Flag("bilateral", &O::bilateral).Flag("temporal", &O::temporal).Flag("clahe", &O::clahe)
        .Number("track_pixels", &O::track_pixels).Text("track_halve", &O::track_halve)
        .Number("video_track_pixels", &O::video_track_pixels).Integer("track_points", &O::track_points)
        .Integer("track_window", &O::track_window)
        .Number("track_turn_deg", &O::track_turn_deg).Number("track_turn_search_deg", &O::track_turn_search_deg)
        .Number("keyframe_overlap", &O::keyframe_overlap).Number("keyframe_min_overlap", &O::keyframe_min_overlap)
        .Flag("follow_back", &O::follow_back).Flag("features_ahead", &O::features_ahead)
        .Number("describe_overlap", &O::describe_overlap).Number("blend_overlap", &O::blend_overlap)
        .Integer("still_track_points", &O::still_track_points).Number("still_describe_overlap", &O::still_describe_overlap)
        .Number("still_blend_overlap", &O::still_blend_overlap).Text("features", &O::features)
        .Integer("max_features", &O::max_features).Integer("followed_max_features", &O::followed_max_features).Number("detect_scale", &O::detect_scale)
        .Number("detect_pixels", &O::detect_pixels).Flag("sift_upsample", &O::sift_upsample)
        .Number("ratio", &O::ratio).Flag("cross_check", &O::cross_check).Flag("fundamental", &O::fundamental)
        .Number("epipolar_threshold", &O::epipolar_threshold).Number("homography_threshold", &O::homography_threshold)
        .Integer("min_inliers", &O::min_inliers).Flag("kalman", &O::kalman).Flag("recover", &O::recover)
        .Flag("patch_fit", &O::patch_fit).Flag("adjust", &O::adjust_patches).Flag("estimate_focal", &O::estimate_focal)
        .Number("patch_robust_loss_px", &O::patch_robust_loss_px)
        .Number("patch_frames_mb", &O::patch_frames_mb).Flag("ecc", &O::ecc).Number("ecc_scale", &O::ecc_scale)
        .Text("ecc_motion", &O::ecc_motion).Number("feather_sigma", &O::feather_sigma)
        .Flag("flat_field", &O::flat_field).Flag("exposure", &O::exposure).Flag("water_colour", &O::water_colour)
        .Number("patch_megapixels", &O::patch_megapixels).Number("patch_memory_mb", &O::patch_memory_mb)
        .Integer("max_lost", &O::max_lost_frames).Integer("max_lost_frames", &O::max_lost_frames)
        .Integer("checkpoint_frames", &O::checkpoint_frames);
    AddTiffOptions(t, &O::tiff);
    return t;
  }();
  return t;
}

}  // namespace

MosaickerOptions MosaickerOptionsFrom(const py::kwargs& kwargs, bool pushed) {
  MosaickerOptions o;
  // Frames pushed one by one leave no first frames to search an overlay in beforehand.
  if (pushed) o.mask = "";
  MosaickerTable().SetAll(o, kwargs, pushed ? "Mosaicker" : "mosaic");
  if (o.mask == "none") o.mask.clear();
  if (pushed && o.mask == "auto")
    throw py::value_error("option 'mask': 'auto' searches the first frames of a folder or video (rolamos.mosaic); "
                          "frames pushed one by one need a mask file or 'none'");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  return o;
}

namespace {

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
  PyMosaicker(const py::object& path, const py::kwargs& kwargs) {
    const MosaickerOptions o = MosaickerOptionsFrom(kwargs, /*pushed=*/true);
    const std::string store = FsPath(path);
    Store s = Store::LooksLikeStore(store) ? Store::Open(store) : Store::Create(store, StoreOptions{});
    mosaicker_ = std::make_unique<Mosaicker>(s, o);
  }
  py::dict Push(const py::handle& frame, std::optional<std::string> name) {
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
    return SummaryDict(s);
  }
  bool closed() const { return !mosaicker_; }

 private:
  std::unique_ptr<Mosaicker> mosaicker_;
  long pushed_ = 0;
};

}  // namespace
}  // namespace rolamos::py_bind

PYBIND11_MODULE(_rolamos, m) {
  using namespace rolamos;
  using namespace rolamos::py_bind;
  m.doc() = "rolamos native bindings (use the rolamos package)";
  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const Error& e) {
      error(e.what());
    } catch (const Interrupted&) {
      PyErr_SetNone(PyExc_KeyboardInterrupt);
    }
  });

  py::class_<Image>(m, "Image", "A tiled image (mosaic, patch or any tiled TIFF) read through a bounded tile cache.")
      .def(py::init([](const py::object& path, double cache_mb) { return Image(FsPath(path), cache_mb); }),
           py::arg("path"), py::arg("cache_mb") = 256.0)
      .def_property_readonly("width", &Image::width, "level-0 width in pixels")
      .def_property_readonly("height", &Image::height, "level-0 height in pixels")
      .def_property_readonly("levels", &Image::levels, "number of pyramid levels")
      .def_property_readonly("channels", &Image::channels, "1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA)")
      .def_property_readonly("dtype", &Image::dtype, "'uint8' or 'uint16'")
      .def_property_readonly("path", &Image::path, "the file read")
      .def_property_readonly("level_sizes", &Image::level_sizes, "(width, height) of every level")
      .def("read", &Image::Read, py::arg("x"), py::arg("y"), py::arg("w"), py::arg("h"), py::arg("level") = 0,
           py::arg("scale") = py::none(),
           "Pixels of a rectangle: at `level` in that level's coordinates, or with `scale` (0 < s <= 1) the "
           "level-0 rectangle resampled. Returns an array (h, w, channels) in RGB(A) order. A window that leaves "
           "the level raises ValueError.");

  py::class_<PyMosaicker>(m, "Mosaicker",
                          "The online engine, fed frame by frame (a camera SDK, a ROS bag): push frames, then "
                          "close(). Options by the CLI's names (rolamos mosaic --help), e.g. fov=60, "
                          "patch_megapixels=5, keyframe_overlap=0.75, mask='overlay.png'.")
      .def(py::init<const py::object&, const py::kwargs&>(), py::arg("store"))
      .def("push", &PyMosaicker::Push, py::arg("frame"), py::arg("name") = py::none(),
           "Maps one frame (uint8 or uint16 array (h, w, 3) RGB, (h, w, 4) RGBA or (h, w) gray); returns the "
           "frame's report (status, reason, patch_id, keyframe, ...).")
      .def("close", &PyMosaicker::Close, "Writes the last patch; returns the run's summary.")
      .def_property_readonly("closed", &PyMosaicker::closed, "whether close() was called");

  BindSteps(m);
  BindObjects(m);
  BindBoxes(m);
  m.def("describe_store", [](const std::string& dir) { return ToPython(DescribeStore(dir)); }, py::arg("path"),
        "What `rolamos info --json` prints for a store.");
  m.def("describe_image", [](const std::string& path) { return ToPython(DescribeImage(path)); }, py::arg("path"),
        "What `rolamos info --json` prints for an image file.");
}
