// JSON <-> store records. Parsing checks every field's presence, type and range and names the
// field in its error; unknown fields are kept ("add, never rename": later versions may add).
#include <cmath>
#include <limits>

#include "rolamos/error.hpp"
#include "rolamos/store.hpp"

namespace rolamos {
namespace {

using json = nlohmann::json;

class Reader {
 public:
  Reader(const json& j, std::string where) : j_(j), where_(std::move(where)) {
    if (!j_.is_object()) Fail(where_, "expected a JSON object");
  }
  const json& Get(const char* key) const {
    auto it = j_.find(key);
    if (it == j_.end()) Fail(where_, std::string("missing field \"") + key + "\"");
    return *it;
  }
  bool Has(const char* key) const { return j_.contains(key) && !j_.at(key).is_null(); }
  std::string Where(const char* key) const { return where_ + ": field \"" + key + "\""; }

  long long Int(const char* key, long long lo, long long hi) const {
    const json& v = Get(key);
    if (!v.is_number_integer()) Fail(Where(key), "must be an integer");
    long long x = v.get<long long>();
    if (x < lo || x > hi)
      Fail(Where(key), std::to_string(x) + " is outside " + std::to_string(lo) + ".." +
                           std::to_string(hi));
    return x;
  }
  double Number(const char* key) const { return NumberOf(Get(key), Where(key)); }
  std::string String(const char* key) const {
    const json& v = Get(key);
    if (!v.is_string()) Fail(Where(key), "must be a string");
    return v.get<std::string>();
  }
  template <size_t N>
  std::array<double, N> Numbers(const char* key) const {
    return NumbersOf<N>(Get(key), Where(key));
  }
  static double NumberOf(const json& v, const std::string& where) {
    if (!v.is_number()) Fail(where, "must be a number");
    double x = v.get<double>();
    if (!std::isfinite(x)) Fail(where, "must be finite");
    return x;
  }
  template <size_t N>
  static std::array<double, N> NumbersOf(const json& v, const std::string& where) {
    if (!v.is_array() || v.size() != N)
      Fail(where, "must be an array of " + std::to_string(N) + " numbers");
    std::array<double, N> a{};
    for (size_t i = 0; i < N; ++i) a[i] = NumberOf(v[i], where + "[" + std::to_string(i) + "]");
    return a;
  }

 private:
  const json& j_;
  std::string where_;
};

json Extra(const json& j, std::initializer_list<const char*> known) {
  json extra = json::object();
  for (auto it = j.begin(); it != j.end(); ++it) {
    bool is_known = false;
    for (const char* k : known) is_known = is_known || it.key() == k;
    if (!is_known) extra[it.key()] = it.value();
  }
  return extra;
}

void CheckHomography(const Homography& h, const std::string& where) {
  const double det = h[0] * (h[4] * h[8] - h[5] * h[7]) - h[1] * (h[3] * h[8] - h[5] * h[6]) +
                     h[2] * (h[3] * h[7] - h[4] * h[6]);
  if (std::abs(det) < 1e-12) Fail(where, "homography is singular");
}

Homography ReadHomography(const Reader& r, const char* key) {
  Homography h = r.Numbers<9>(key);
  CheckHomography(h, r.Where(key));
  return h;
}

constexpr long long kMaxInt = 2147483647LL;

}  // namespace

Homography IdentityHomography() { return {1, 0, 0, 0, 1, 0, 0, 0, 1}; }

json SidecarToJson(const PatchSidecar& s) {
  json j = s.extra;
  j["id"] = s.id;
  j["size"] = s.size;
  j["n_images"] = s.n_images;
  j["offset"] = s.offset;
  j["first_homography"] = s.first_homography;
  j["last_homography"] = s.last_homography;
  j["patch_to_global"] = s.patch_to_global ? json(*s.patch_to_global) : json(nullptr);
  json frames = json::array();
  for (const auto& f : s.frames) {
    json fj = f.extra;
    fj["index"] = f.index;
    fj["source"] = f.source;
    fj["frame_to_patch"] = f.frame_to_patch;
    fj["egomotion"] = f.egomotion ? json{{"R", f.egomotion->R},
                                         {"t", f.egomotion->t},
                                         {"n", f.egomotion->n}}
                                  : json(nullptr);
    fj["matches"] = f.matches;
    fj["inliers"] = f.inliers;
    fj["ecc"] = f.ecc;
    fj["status"] = f.status;
    if (f.bilateral_error) fj["bilateral_error"] = *f.bilateral_error;
    if (f.ecc_shift_px) fj["ecc_shift_px"] = *f.ecc_shift_px;
    if (f.frame_to_global) fj["frame_to_global"] = *f.frame_to_global;
    if (f.residual_px) fj["residual_px"] = *f.residual_px;
    if (f.uncertainty_px) fj["uncertainty_px"] = *f.uncertainty_px;
    if (f.align_edges) fj["align_edges"] = *f.align_edges;
    if (f.placement_doubtful) fj["placement_doubtful"] = *f.placement_doubtful;
    if (f.registered_by) fj["registered_by"] = *f.registered_by;
    if (f.doubtful) fj["doubtful"] = *f.doubtful;
    if (f.patch_frames) fj["patch_frames"] = *f.patch_frames;
    if (f.keyframe) fj["keyframe"] = *f.keyframe;
    if (f.placed_from) fj["placed_from"] = *f.placed_from;
    if (f.described) fj["described"] = *f.described;
    if (f.blended) fj["blended"] = *f.blended;
    frames.push_back(std::move(fj));
  }
  j["frames"] = std::move(frames);
  json rejected = json::array();
  for (const auto& r : s.rejected)
    rejected.push_back({{"index", r.index}, {"source", r.source}, {"reason", r.reason}});
  j["rejected"] = std::move(rejected);
  if (s.link) {
    json l = {{"previous_patch", s.link->previous_patch}, {"to_previous", s.link->to_previous}};
    if (!s.link->method.empty()) l["method"] = s.link->method;
    if (s.link->inliers) l["inliers"] = *s.link->inliers;
    j["link"] = std::move(l);
  }
  if (s.pixel_budget) j["pixel_budget"] = *s.pixel_budget;
  if (s.frame_size) j["frame_size"] = *s.frame_size;
  if (s.frame_camera_matrix) j["frame_camera_matrix"] = *s.frame_camera_matrix;
  if (s.patch_to_global_online) j["patch_to_global_online"] = *s.patch_to_global_online;
  if (s.aligned) j["aligned"] = *s.aligned;
  if (s.closed_by) j["closed_by"] = *s.closed_by;
  if (s.frame_links) j["frame_links"] = *s.frame_links;
  if (s.frame_features) j["frame_features"] = *s.frame_features;
  if (s.component) j["component"] = *s.component;
  return j;
}

PatchSidecar SidecarFromJson(const json& j, const std::string& where) {
  Reader r(j, where);
  PatchSidecar s;
  s.id = static_cast<int>(r.Int("id", 1, 999999));
  const auto size = r.Numbers<2>("size");
  for (int i = 0; i < 2; ++i) {
    if (size[i] < 1 || size[i] > kMaxInt || size[i] != std::floor(size[i]))
      Fail(r.Where("size"), "must be two whole numbers from 1 to 2^31-1");
    s.size[i] = static_cast<long long>(size[i]);
  }
  s.n_images = static_cast<int>(r.Int("n_images", 0, kMaxInt));
  s.offset = r.Numbers<2>("offset");
  s.first_homography = ReadHomography(r, "first_homography");
  s.last_homography = ReadHomography(r, "last_homography");
  if (r.Has("patch_to_global")) s.patch_to_global = ReadHomography(r, "patch_to_global");
  const json& frames = r.Get("frames");
  if (!frames.is_array()) Fail(r.Where("frames"), "must be an array");
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string fw = where + ": frames[" + std::to_string(i) + "]";
    Reader fr(frames[i], fw);
    FrameRecord f;
    f.index = static_cast<int>(fr.Int("index", 0, kMaxInt));
    f.source = fr.String("source");
    f.frame_to_patch = ReadHomography(fr, "frame_to_patch");
    if (fr.Has("egomotion")) {
      Reader er(fr.Get("egomotion"), fw + ": egomotion");
      Egomotion e;
      e.R = er.Numbers<9>("R");
      e.t = er.Numbers<3>("t");
      e.n = er.Numbers<3>("n");
      f.egomotion = e;
    }
    f.matches = static_cast<int>(fr.Int("matches", 0, kMaxInt));
    f.inliers = static_cast<int>(fr.Int("inliers", 0, kMaxInt));
    f.ecc = fr.Number("ecc");
    f.status = fr.String("status");
    if (fr.Has("bilateral_error")) f.bilateral_error = fr.Number("bilateral_error");
    if (fr.Has("ecc_shift_px")) f.ecc_shift_px = fr.Number("ecc_shift_px");
    if (fr.Has("frame_to_global")) f.frame_to_global = ReadHomography(fr, "frame_to_global");
    if (fr.Has("registered_by")) f.registered_by = fr.String("registered_by");
    if (fr.Has("doubtful")) {
      if (!fr.Get("doubtful").is_boolean()) Fail(fr.Where("doubtful"), "must be true or false");
      f.doubtful = fr.Get("doubtful").get<bool>();
    }
    if (fr.Has("patch_frames")) f.patch_frames = static_cast<int>(fr.Int("patch_frames", 0, kMaxInt));
    if (fr.Has("keyframe")) {
      if (!fr.Get("keyframe").is_boolean()) Fail(fr.Where("keyframe"), "must be true or false");
      f.keyframe = fr.Get("keyframe").get<bool>();
    }
    if (fr.Has("placed_from")) f.placed_from = static_cast<int>(fr.Int("placed_from", 0, kMaxInt));
    if (fr.Has("residual_px")) f.residual_px = fr.Number("residual_px");
    if (fr.Has("uncertainty_px")) f.uncertainty_px = fr.Number("uncertainty_px");
    if (fr.Has("align_edges")) f.align_edges = static_cast<int>(fr.Int("align_edges", 0, kMaxInt));
    if (fr.Has("placement_doubtful")) {
      if (!fr.Get("placement_doubtful").is_boolean()) Fail(fr.Where("placement_doubtful"), "must be true or false");
      f.placement_doubtful = fr.Get("placement_doubtful").get<bool>();
    }
    if (fr.Has("described")) {
      if (!fr.Get("described").is_boolean()) Fail(fr.Where("described"), "must be true or false");
      f.described = fr.Get("described").get<bool>();
    }
    if (fr.Has("blended")) {
      if (!fr.Get("blended").is_boolean()) Fail(fr.Where("blended"), "must be true or false");
      f.blended = fr.Get("blended").get<bool>();
    }
    f.extra = Extra(frames[i], {"index", "source", "frame_to_patch", "egomotion", "matches",
                                "inliers", "ecc", "status", "bilateral_error", "ecc_shift_px",
                                "frame_to_global", "registered_by", "doubtful", "patch_frames",
                                "keyframe", "placed_from", "described", "blended", "residual_px", "uncertainty_px",
                                "align_edges", "placement_doubtful"});
    s.frames.push_back(std::move(f));
  }
  const json& rejected = r.Get("rejected");
  if (!rejected.is_array()) Fail(r.Where("rejected"), "must be an array");
  for (size_t i = 0; i < rejected.size(); ++i) {
    Reader rr(rejected[i], where + ": rejected[" + std::to_string(i) + "]");
    RejectedFrame f;
    f.index = static_cast<int>(rr.Int("index", 0, kMaxInt));
    f.source = rr.String("source");
    f.reason = rr.String("reason");
    s.rejected.push_back(std::move(f));
  }
  if (r.Has("link")) {
    Reader lr(r.Get("link"), r.Where("link"));
    PatchLink l;
    l.previous_patch = static_cast<int>(lr.Int("previous_patch", 1, 999999));
    l.to_previous = ReadHomography(lr, "to_previous");
    if (lr.Has("method")) l.method = lr.String("method");
    if (lr.Has("inliers")) l.inliers = static_cast<int>(lr.Int("inliers", 0, kMaxInt));
    s.link = l;
  }
  if (r.Has("pixel_budget")) s.pixel_budget = r.Int("pixel_budget", 0, std::numeric_limits<long long>::max());
  if (r.Has("frame_size")) {
    const auto fs = r.Numbers<2>("frame_size");
    std::array<int, 2> size{};
    for (size_t i = 0; i < 2; ++i) {
      if (fs[i] < 1 || fs[i] > kMaxInt || fs[i] != std::floor(fs[i]))
        Fail(r.Where("frame_size"), "must be two whole numbers from 1 to 2^31-1");
      size[i] = static_cast<int>(fs[i]);
    }
    s.frame_size = size;
  }
  if (r.Has("frame_camera_matrix")) s.frame_camera_matrix = ReadHomography(r, "frame_camera_matrix");
  if (r.Has("patch_to_global_online")) s.patch_to_global_online = ReadHomography(r, "patch_to_global_online");
  if (r.Has("aligned")) {
    if (!r.Get("aligned").is_boolean()) Fail(r.Where("aligned"), "must be true or false");
    s.aligned = r.Get("aligned").get<bool>();
  }
  if (r.Has("closed_by")) s.closed_by = r.String("closed_by");
  if (r.Has("frame_links")) s.frame_links = r.String("frame_links");
  if (r.Has("frame_features")) s.frame_features = r.String("frame_features");
  if (r.Has("component")) s.component = static_cast<int>(r.Int("component", 0, kMaxInt));
  s.extra = Extra(j, {"id", "size", "n_images", "offset", "first_homography", "last_homography",
                      "patch_to_global", "frames", "rejected", "link", "pixel_budget", "frame_size",
                      "frame_camera_matrix", "patch_to_global_online", "aligned", "closed_by", "frame_links", "frame_features",
                      "component"});
  return s;
}

PatchSidecar ParseSidecar(const std::string& text, const std::string& where) {
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) Fail(where, "is not valid JSON");
  return SidecarFromJson(j, where);
}

json GlobalToJson(const GlobalRecord& g) {
  json j;
  j["size"] = g.size;
  j["offset"] = g.offset;
  j["n_images"] = g.n_images;
  j["n_patches"] = g.n_patches;
  j["scale"] = g.scale;
  j["crs"] = g.georef ? json(g.georef->crs) : json(nullptr);
  j["geotransform"] = g.georef ? json(g.georef->geotransform) : json(nullptr);
  return j;
}

GlobalRecord GlobalFromJson(const json& j, const std::string& where) {
  Reader r(j, where);
  GlobalRecord g;
  const auto size = r.Numbers<2>("size");
  for (int i = 0; i < 2; ++i) {
    if (size[i] < 0 || size[i] > kMaxInt || size[i] != std::floor(size[i]))
      Fail(r.Where("size"), "must be two whole numbers from 0 to 2^31-1");
    g.size[i] = static_cast<long long>(size[i]);
  }
  g.offset = r.Numbers<2>("offset");
  g.n_images = static_cast<int>(r.Int("n_images", 0, kMaxInt));
  g.n_patches = static_cast<int>(r.Int("n_patches", 0, kMaxInt));
  g.scale = r.Number("scale");
  if (!(g.scale > 0)) Fail(r.Where("scale"), "must be positive");
  if (r.Has("crs") || r.Has("geotransform")) {
    Georef geo;
    geo.crs = r.String("crs");
    geo.geotransform = r.Numbers<6>("geotransform");
    std::string error;
    if (!geo.IsValid(&error)) Fail(where, "georeference: " + error);
    g.georef = geo;
  }
  return g;
}

}  // namespace rolamos
