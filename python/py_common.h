// What the rolamos Python bindings share: pixels as NumPy arrays in RGB(A) order, JSON as Python
// objects, keyword options by the CLI's names, and progress callbacks that honour Ctrl-C.
#pragma once

#include <atomic>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <functional>
#include <map>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "rolamos/image_format.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/progress.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos::py_bind {

namespace py = pybind11;

// A str or os.PathLike as a path string.
inline std::string FsPath(const py::handle& p) { return py::str(py::module_::import("os").attr("fspath")(p)); }

// JSON into Python objects, through the json module (exact types, nested).
py::object ToPython(const nlohmann::json& j);
// OpenCV's BGR(A)/gray Mat -> a NumPy array (h, w, c) in RGB(A) order, owning its copy.
py::array ToArray(cv::Mat m);
// A NumPy frame (h, w, 3) RGB, (h, w, 4) RGBA or (h, w) gray, uint8 -> BGR Mat (a copy); ValueError
// naming what was wrong otherwise.
cv::Mat FromArray(const py::handle& a);

// Ctrl-C during a long library call made without the GIL. Python's own SIGINT handler runs only
// once the call returns, so for the call's length SIGINT sets a flag instead (main thread only;
// restored after), the call's progress callbacks throw Interrupted on whichever thread they run,
// and the call ends as KeyboardInterrupt. Library writes are atomic: nothing half-written stays.
class InterruptScope {
 public:
  InterruptScope();
  ~InterruptScope();
  InterruptScope(const InterruptScope&) = delete;
  InterruptScope& operator=(const InterruptScope&) = delete;

 private:
  bool installed_ = false;
};
struct Interrupted : std::exception {
  const char* what() const noexcept override { return "interrupted (Ctrl-C)"; }
};
// Set by Ctrl-C within an InterruptScope: for calls that end cleanly on a stop flag (mosaic writes
// its open patch) before Interrupted is thrown.
const std::atomic<bool>* InterruptFlag();

// A library progress callback: honours Ctrl-C (InterruptScope) and calls the user's
// `progress(fraction, message)` when given, taking the GIL (from any thread). Make it while
// holding the GIL, before releasing it for the call.
ProgressFn PythonProgress(const py::object& progress, const std::string& message);

// Keyword options by the CLI's names (dashes or underscores), each converted to its field's
// type. An unknown name or a value of the wrong type raises ValueError naming the option.
template <typename T>
class OptionTable {
 public:
  using Setter = std::function<void(T&, const py::handle&)>;
  OptionTable& Number(const std::string& name, double T::*f) {
    setters_[name] = [f](T& o, const py::handle& v) { o.*f = v.cast<double>(); };
    return *this;
  }
  OptionTable& Integer(const std::string& name, int T::*f) {
    setters_[name] = [f](T& o, const py::handle& v) { o.*f = v.cast<int>(); };
    return *this;
  }
  OptionTable& Flag(const std::string& name, bool T::*f) {
    setters_[name] = [f](T& o, const py::handle& v) { o.*f = v.cast<bool>(); };
    return *this;
  }
  OptionTable& Text(const std::string& name, std::string T::*f) {
    setters_[name] = [f](T& o, const py::handle& v) { o.*f = v.cast<std::string>(); };
    return *this;
  }
  OptionTable& Custom(const std::string& name, Setter s) {
    setters_[name] = std::move(s);
    return *this;
  }
  void Set(T& o, std::string name, const py::handle& v, const std::string& what) const {
    for (char& c : name)
      if (c == '-') c = '_';
    auto it = setters_.find(name);
    if (it == setters_.end()) throw py::value_error("unknown option '" + name + "' (see help(rolamos." + what + "))");
    try {
      it->second(o, v);
    } catch (const py::cast_error&) {
      throw py::value_error("option '" + name + "': wrong type (" + std::string(py::str(v.get_type())) + ")");
    }
  }
  void SetAll(T& o, const py::kwargs& kwargs, const std::string& what) const {
    for (const auto& [k, v] : kwargs) Set(o, k.cast<std::string>(), v, what);
  }

 private:
  std::map<std::string, Setter> setters_;
};

// The CLI's codec switches (--compression, --quality, --tile, --threads, --zstd-level,
// --webp-method) for any options struct that holds a TiffWriteOptions.
template <typename T>
void AddTiffOptions(OptionTable<T>& table, TiffWriteOptions T::*tiff) {
  table.Custom("compression", [tiff](T& o, const py::handle& v) {
    const std::string name = v.cast<std::string>();
    if (!ParseCompression(name, &(o.*tiff).compression))
      throw py::value_error("option 'compression': unknown codec '" + name + "' (none, jpeg, jpeg-mask, deflate, zstd or webp)");
  });
  table.Custom("quality", [tiff](T& o, const py::handle& v) { (o.*tiff).quality = v.cast<int>(); });
  table.Custom("tile", [tiff](T& o, const py::handle& v) { (o.*tiff).tile_size = v.cast<int>(); });
  table.Custom("threads", [tiff](T& o, const py::handle& v) { (o.*tiff).threads = v.cast<int>(); });
  table.Custom("zstd_level", [tiff](T& o, const py::handle& v) { (o.*tiff).zstd_level = v.cast<int>(); });
  table.Custom("webp_method", [tiff](T& o, const py::handle& v) { (o.*tiff).webp_method = v.cast<int>(); });
}

// The engine's options from keyword arguments (rolamos mosaic's names). `pushed`: for frames
// pushed one by one (no overlay search: mask "" by default, "auto" refused).
MosaickerOptions MosaickerOptionsFrom(const py::kwargs& kwargs, bool pushed);
// A run's summary as a dictionary.
py::dict SummaryDict(const MosaicSummary& s);

// Registration of the module's parts (python/*.cc).
void BindSteps(py::module_& m);    // synth, mosaic, compose, align, merge, export, convert
void BindObjects(py::module_& m);  // objects: train, evaluate, detect
void BindBoxes(py::module_& m);    // objects with boxes: train, evaluate, validate, detect

}  // namespace rolamos::py_bind
