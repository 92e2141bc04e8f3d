// Every step of the `rolamos` command as a Python function: synth, mosaic, compose, align, merge,
// export and convert. Each fills the library's options from keyword arguments named as the CLI's
// switches (validated by the library's IsValid: ValueError naming the option) and calls the same
// library function the CLI calls, without the GIL, with progress and Ctrl-C.
#include <pybind11/stl.h>

#include <optional>

#include "py_common.h"
#include "rolamos/compose.hpp"
#include "rolamos/convert.hpp"
#include "rolamos/error.hpp"
#include "rolamos/georeference.hpp"
#include "rolamos/global_align.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/store.hpp"
#include "rolamos/store_merge.hpp"
#include "rolamos/survey.hpp"
#include "rolamos/tiled_image.hpp"
#include "store/writer_lock.h"

namespace rolamos::py_bind {

namespace {

// ---- synth ---------------------------------------------------------------------------------

const OptionTable<SurveyOptions>& SurveyTable() {
  static const OptionTable<SurveyOptions> t = [] {
    OptionTable<SurveyOptions> t;
    t.Integer("frames", &SurveyOptions::frames).Text("path", &SurveyOptions::path)
        .Integer("width", &SurveyOptions::frame_width).Integer("height", &SurveyOptions::frame_height)
        .Number("focal", &SurveyOptions::focal_px).Number("fov", &SurveyOptions::fov_deg)
        .Number("gsd", &SurveyOptions::gsd).Number("overlap", &SurveyOptions::forward_overlap)
        .Number("side_overlap", &SurveyOptions::side_overlap).Number("tilt", &SurveyOptions::tilt_deg)
        .Number("attitude_jitter", &SurveyOptions::attitude_jitter_deg).Flag("turns", &SurveyOptions::lane_turns)
        .Integer("lanes", &SurveyOptions::lanes).Number("max_turn", &SurveyOptions::max_turn_deg)
        .Flag("overlay", &SurveyOptions::overlay).Number("altitude_jitter", &SurveyOptions::altitude_jitter)
        .Text("repeat", &SurveyOptions::repeat)
        .Number("attenuation", &SurveyOptions::attenuation).Number("vignetting", &SurveyOptions::vignetting)
        .Number("backscatter", &SurveyOptions::backscatter).Number("light_cone", &SurveyOptions::light_cone)
        .Number("k1", &SurveyOptions::k1)
        .Number("exposure_jitter", &SurveyOptions::exposure_jitter).Number("motion_blur", &SurveyOptions::motion_blur)
        .Number("descent_from", &SurveyOptions::descent_from).Integer("descent_frames", &SurveyOptions::descent_frames).Number("noise", &SurveyOptions::noise)
        .Integer("particles", &SurveyOptions::particles).Integer("jpeg", &SurveyOptions::jpeg_quality)
        .Custom("seed", [](SurveyOptions& o, const py::handle& v) { o.seed = v.cast<uint32_t>(); })
        .Text("video", &SurveyOptions::video).Number("video_fps", &SurveyOptions::video_fps)
        .Text("video_codec", &SurveyOptions::video_codec);
    return t;
  }();
  return t;
}

py::dict Synth(const py::object& output, const py::object& texture, const py::object& progress,
               const py::kwargs& kwargs) {
  SurveyOptions o;
  if (!texture.is_none()) {
    if (py::isinstance<py::str>(texture) || py::hasattr(texture, "__fspath__")) {
      o.texture = FsPath(texture);
    } else {
      for (const auto& t : texture) o.texture += (o.texture.empty() ? "" : ",") + FsPath(t);
    }
  }
  SurveyTable().SetAll(o, kwargs, "synth");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  const std::string dir = FsPath(output);
  Survey s;
  const ProgressFn report = PythonProgress(progress, "synth");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    s = WriteSurvey(o, dir, report);
  }
  py::dict d;
  d["path"] = dir;
  d["frames"] = s.frames.size();
  d["frame_size"] = py::make_tuple(s.frame_size.width, s.frame_size.height);
  d["texture"] = s.texture;
  d["texture_size"] = py::make_tuple(s.texture_size.width, s.texture_size.height);
  return d;
}

}  // namespace

py::dict SummaryDict(const MosaicSummary& s) {
  py::dict d;
  d["frames"] = s.frames;
  d["stitched"] = s.stitched;
  d["rejected"] = s.rejected;
  d["patches"] = s.patches;
  d["keyframes"] = s.keyframes;
  d["blended"] = s.blended;
  d["described"] = s.described;
  d["recovered"] = s.recovered;
  d["adjusted"] = s.adjusted;
  py::list unadjusted;
  for (const auto& [id, why] : s.unadjusted_why) unadjusted.append(py::make_tuple(id, why));
  d["unadjusted"] = unadjusted;  // (patch, why): the patches whose online placements were kept
  py::list rejected_frames;
  for (const auto& r : s.rejected_frames) rejected_frames.append(py::make_tuple(r.index, r.source, r.reason));
  d["rejected_frames"] = rejected_frames;  // (index, source, reason) of every frame rejected for good
  d["misfit_patches"] = s.misfit_patches;  // of those: frames that fit no flat ground through a pinhole
  d["trivial_patches"] = s.trivial_patches;  // of those: fewer than three frames
  d["seconds"] = s.seconds;
  d["cpu_seconds"] = s.cpu_seconds;
  d["peak_rss_mb"] = s.peak_rss_mb;
  py::dict stages;
  for (const auto& [name, sec] : s.stage_seconds) stages[py::str(name)] = sec;
  d["stage_seconds"] = stages;
  d["rest_cpu_seconds"] = s.RestCpuSeconds();  // CPU no stage names (OpenCV's helper threads)
  d["calibration_note"] = s.calibration_note;
  d["mask_note"] = s.mask_note;
  d["track_scale"] = s.track_scale;  // frames followed at this fraction of their size
  return d;
}

namespace {

// ---- mosaic (folder, list or video) -----------------------------------------------------------

py::dict Mosaic(const py::object& input, const py::object& store, const py::object& progress, const py::kwargs& kwargs) {
  MosaickerOptions o = MosaickerOptionsFrom(kwargs, /*pushed=*/false);
  const std::string in = FsPath(input), dir = FsPath(store);
  MosaicSummary s;
  const ProgressFn report = PythonProgress(progress, "mosaic");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    CheckMosaicInput(in);  // before the store is made
    Store st = Store::LooksLikeStore(dir) ? Store::Open(dir) : Store::Create(dir, StoreOptions{});
    // Ctrl-C ends the run as the end of the input would (the open patch written), then raises
    // KeyboardInterrupt: what was mapped stays in the store.
    s = MosaicInput(
        in, st, o,
        [&](const FrameReport& r, int total) {
          try {
            report(total > 0 ? std::min(1.0, double(r.index + 1) / total) : 0.0);
          } catch (const Interrupted&) {  // the stop flag ends the run instead
          }
        },
        InterruptFlag());
  }
  if (s.stopped) throw Interrupted();
  return SummaryDict(s);
}

// ---- compose, align, merge, export, convert ------------------------------------------------------

py::dict Compose(const py::object& store, const py::object& navigation, double focal, double altitude,
                 const std::string& crs, const py::object& progress, const py::kwargs& kwargs) {
  ComposeOptions o;
  // The CLI's defaults (rolamos compose): WebP at quality 90 in 256-pixel tiles.
  o.tiff.compression = Compression::kWebp;
  o.tiff.quality = 90;
  static const OptionTable<ComposeOptions> table = [] {
    OptionTable<ComposeOptions> t;
    t.Custom("max_pixels", [](ComposeOptions& o, const py::handle& v) { o.max_pixels = v.cast<long long>(); })
        .Number("cache_mb", &ComposeOptions::cache_mb).Integer("feather_px", &ComposeOptions::feather_px)
        .Integer("bands", &ComposeOptions::bands).Flag("exposure", &ComposeOptions::exposure)
        .Flag("restart", &ComposeOptions::restart).Integer("chunk", &ComposeOptions::chunk_px)
        .Custom("blend", [](ComposeOptions& o, const py::handle& v) {
          const std::string b = v.cast<std::string>();
          if (b == "multiband") o.bands = o.bands > 0 ? o.bands : 5;
          else if (b == "feather") o.bands = 0;
          else throw py::value_error("option 'blend': '" + b + "' is not feather or multiband");
        });
    AddTiffOptions(t, &ComposeOptions::tiff);
    return t;
  }();
  table.SetAll(o, kwargs, "compose");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  if (altitude < 0 || (altitude > 0 && !(focal > 0)))
    throw py::value_error("altitude needs a positive value and focal (pixels) for the local frame's pixel size");
  if (altitude > 0 && !navigation.is_none())
    throw py::value_error("altitude gives a local frame for surveys without navigation; with navigation, the "
                          "vehicle's altitude goes in the navigation CSV");
  const std::string dir = FsPath(store);
  const std::string nav = navigation.is_none() ? "" : FsPath(navigation);
  ComposeResult r;
  std::optional<GeoreferenceResult> geo;
  const ProgressFn report = PythonProgress(progress, "compose");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    Store st = Store::Open(dir);
    // Composing and georeferencing both change the store: held once across them, as the CLI does.
    const auto lock = o.shards > 0 && !o.finish ? nullptr : LockStoreForChange(st, "rolamos compose");
    r = ComposeMosaic(st, o, report);
    if (!nav.empty()) {
      NavigationCamera camera;
      camera.focal_px = focal;
      geo = GeoreferenceMosaic(st, ReadNavigationCsv(nav, FrameCamera(st, camera), crs));
    } else if (altitude > 0) {
      GeoreferenceLocal(st, altitude / focal);
    }
  }
  py::dict d;
  d["width"] = r.width;
  d["height"] = r.height;
  d["scale"] = r.scale;
  d["patches_used"] = r.patches_used;
  py::list left;
  for (const auto& [id, why] : r.left_out) left.append(py::make_tuple(id, why));
  d["left_out"] = left;
  d["chunks_resumed"] = r.chunks_resumed;
  if (geo) {
    d["crs"] = geo->georef.crs;
    d["frames_georeferenced"] = geo->frames_used;
    d["residual_median_m"] = geo->median_residual_m;
    d["residual_max_m"] = geo->max_residual_m;
  }
  return d;
}

py::dict Align(const py::object& store, const py::object& navigation, double focal, const std::string& crs,
               const py::object& progress, const py::kwargs& kwargs) {
  AlignOptions o;
  static const OptionTable<AlignOptions> table = [] {
    OptionTable<AlignOptions> t;
    t.Text("frames", &AlignOptions::frames_dir).Integer("retrieval_candidates", &AlignOptions::retrieval_candidates)
        .Integer("loops_per_frame", &AlignOptions::loops_per_frame).Number("loop_overlap", &AlignOptions::loop_overlap)
        .Integer("min_inliers", &AlignOptions::min_inliers).Number("loss_px", &AlignOptions::loss_px)
        .Integer("pairs_per_edge", &AlignOptions::pairs_per_edge)
        .Integer("points_per_edge", &AlignOptions::points_per_edge)
        .Number("scatter_floor_px", &AlignOptions::scatter_floor_px).Number("edge_loss_px", &AlignOptions::edge_loss_px)
        .Number("navigation_sigma", &AlignOptions::navigation_sigma_m).Integer("threads", &AlignOptions::threads);
    return t;
  }();
  table.SetAll(o, kwargs, "align");
  const std::string dir = FsPath(store);
  if (!navigation.is_none()) {
    NavigationCamera camera;
    camera.focal_px = focal;
    o.navigation = ReadNavigationCsv(FsPath(navigation), FrameCamera(Store::Open(dir), camera), crs);
  }
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  AlignSummary r;
  const ProgressFn report = PythonProgress(progress, "align");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    r = AlignStore(Store::Open(dir), o, report);
  }
  py::dict d;
  d["frames"] = r.frames;
  d["components"] = r.components;
  d["component_frames"] = r.component_frames;
  d["online_edges"] = r.online_edges;
  d["retrieval_edges"] = r.retrieval_edges;
  d["rejoin_edges"] = r.rejoin_edges;
  d["loop_edges"] = r.loop_edges;
  d["edges_dropped"] = r.edges_dropped;
  d["rms_before_px"] = r.rms_before_px;
  d["rms_after_px"] = r.rms_after_px;
  d["seconds"] = r.seconds;
  py::dict stages, peaks;
  for (const auto& st : r.stages) {
    stages[py::str(st.name)] = st.seconds;
    peaks[py::str(st.name)] = st.peak_mib;
  }
  d["stage_seconds"] = stages;
  d["stage_peak_mib"] = peaks;
  return d;
}

py::dict Merge(const std::vector<py::object>& stores, const py::object& output, const py::object& progress) {
  std::vector<std::string> inputs;
  for (const auto& s : stores) inputs.push_back(FsPath(s));
  if (inputs.empty()) throw py::value_error("stores: give at least one store to merge");
  const std::string out = FsPath(output);
  MergeSummary r;
  const ProgressFn report = PythonProgress(progress, "merge");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    r = MergeStores(inputs, out, report);
  }
  py::dict d;
  d["stores"] = r.stores;
  d["patches"] = r.patches;
  d["frames"] = r.frames;
  d["linked"] = r.linked;
  d["seconds"] = r.seconds;
  return d;
}

py::dict Export(const py::object& image, const py::object& output, std::optional<std::vector<double>> region,
                int level, double scale, int jpeg_quality, const py::object& progress, const py::kwargs& kwargs) {
  ExportOptions o;
  o.output = FsPath(output);
  o.level = level;
  o.scale = scale;
  o.jpeg_quality = jpeg_quality;
  static const OptionTable<ExportOptions> table = [] {
    OptionTable<ExportOptions> t;
    AddTiffOptions(t, &ExportOptions::tiff);
    return t;
  }();
  table.SetAll(o, kwargs, "export");
  if (region) {
    if (region->size() != 4) throw py::value_error("region: expected (x, y, w, h)");
    o.region = cv::Rect2d((*region)[0], (*region)[1], (*region)[2], (*region)[3]);
  }
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  const std::string path = FsPath(image);
  ExportResult r;
  const ProgressFn report = PythonProgress(progress, "export");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    const TiledImage source = TiledImage::Open(path);
    r = ExportRegion(source, o, report);
  }
  py::dict d;
  d["path"] = o.output;
  d["width"] = r.width;
  d["height"] = r.height;
  d["level"] = r.level;
  d["scale"] = r.scale;
  return d;
}

py::dict Convert(const py::object& input, const py::object& output, double cache_mb, const py::object& progress,
                 const py::kwargs& kwargs) {
  ConvertOptions o;
  o.input = FsPath(input);
  o.output = FsPath(output);
  o.cache_mb = cache_mb;
  static const OptionTable<ConvertOptions> table = [] {
    OptionTable<ConvertOptions> t;
    AddTiffOptions(t, &ConvertOptions::tiff);
    return t;
  }();
  table.SetAll(o, kwargs, "convert");
  std::string error;
  if (!o.IsValid(&error)) throw py::value_error(error);
  ConvertResult r;
  const ProgressFn report = PythonProgress(progress, "convert");
  InterruptScope interrupt;
  {
    py::gil_scoped_release release;
    r = ConvertImage(o, report);
  }
  py::dict d;
  d["width"] = r.width;
  d["height"] = r.height;
  d["channels"] = r.channels;
  d["levels"] = r.stats.levels;
  d["tiles"] = r.stats.tiles;
  d["bytes"] = r.stats.bytes;
  d["reader"] = r.reader;
  return d;
}

}  // namespace

void BindSteps(py::module_& m) {
  m.def("synth", &Synth, py::arg("output"), py::kw_only(), py::arg("texture") = py::none(),
        py::arg("progress") = py::none(),
        "A synthetic survey with ground truth (rolamos synth) over `texture` (an image, a list of images as "
        "bands, or None: a procedural seafloor): frames/ and ground_truth.json in `output`. Options by the "
        "CLI's names: frames, path, width, height, focal, fov, gsd, overlap, side_overlap, tilt, "
        "attitude_jitter, turns, lanes, max_turn, overlay, altitude_jitter, attenuation, vignetting, "
        "backscatter, light_cone, exposure_jitter, motion_blur, descent_from, descent_frames, noise, particles, jpeg, seed, video, video_fps, video_codec.");
  m.def("mosaic", &Mosaic, py::arg("input"), py::arg("store"), py::kw_only(), py::arg("progress") = py::none(),
        "The online engine over a folder of frames, a .txt list or a video (rolamos mosaic), into `store` "
        "(created when new). Options as rolamos.Mosaicker's, with the CLI's defaults (mask='auto' finds a "
        "burned-in overlay in the first frames). Returns the run's summary.");
  m.def("compose", &Compose, py::arg("store"), py::kw_only(), py::arg("navigation") = py::none(),
        py::arg("focal") = 0.0, py::arg("altitude") = 0.0, py::arg("crs") = "", py::arg("progress") = py::none(),
        "Composes the store's patches into mosaic.tif (rolamos compose). navigation: a CSV as the CLI's "
        "--navigation (with focal for vehicle navigation); altitude and focal: a local frame in metres. Options: "
        "max_pixels, cache_mb, feather_px, blend ('feather' or 'multiband'), bands, exposure, restart, chunk, "
        "compression, quality, tile, threads, zstd_level, webp_method. Ctrl-C interrupts it (a later compose "
        "resumes).");
  m.def("align", &Align, py::arg("store"), py::kw_only(), py::arg("navigation") = py::none(), py::arg("focal") = 0.0,
        py::arg("crs") = "", py::arg("progress") = py::none(),
        "The global map over every frame (rolamos align); compose then draws it. Options: frames, "
        "retrieval_candidates, loops_per_frame, loop_overlap, min_inliers, loss_px, pairs_per_edge, points_per_edge, "
        "scatter_floor_px, edge_loss_px, navigation_sigma, threads.");
  m.def("merge", &Merge, py::arg("stores"), py::arg("output"), py::kw_only(), py::arg("progress") = py::none(),
        "Several stores (dives) as one new store (rolamos merge); align it to find where they meet.");
  m.def("export", &Export, py::arg("image"), py::arg("output"), py::kw_only(), py::arg("region") = py::none(),
        py::arg("level") = -1, py::arg("scale") = 1.0, py::arg("jpeg_quality") = 92, py::arg("progress") = py::none(),
        "A region (x, y, w, h in level-0 pixels) of a tiled image to .tif (streamed, pyramidal, keeps the "
        "georeference), .png or .jpg (rolamos export). Codec options for .tif as convert's.");
  m.def("convert", &Convert, py::arg("input"), py::arg("output"), py::kw_only(), py::arg("cache_mb") = 16.0,
        py::arg("progress") = py::none(),
        "Any image OpenImageIO or GDAL reads into a pyramidal tiled BigTIFF (rolamos convert). Options: "
        "compression (default jpeg), quality, tile, threads, zstd_level, webp_method.");
}

}  // namespace rolamos::py_bind
