#include "rolamos/store.hpp"

#include <algorithm>

#include <cstdio>
#include <filesystem>

#include "rolamos/error.hpp"
#include "rolamos/version.hpp"
#include "store/writer_lock.h"
#include "util/files.h"

namespace fs = std::filesystem;

namespace rolamos {
namespace {

using json = nlohmann::json;

constexpr const char* kManifest = "store.json";
constexpr const char* kMosaic = "mosaic.tif";

std::string PatchStem(int id) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "patches/%06d", id);
  return buf;
}

// Paths in the manifest are relative and stay inside the store.
void CheckRelative(const std::string& rel, const std::string& where) {
  fs::path p(rel);
  if (rel.empty() || p.is_absolute()) Fail(where, "\"" + rel + "\" must be a relative path");
  for (const auto& part : p)
    if (part == "..") Fail(where, "\"" + rel + "\" leaves the store");
}

}  // namespace

std::string Store::ManifestPath() const { return (fs::path(dir_) / kManifest).string(); }
std::string Store::MosaicPath() const { return (fs::path(dir_) / kMosaic).string(); }
bool Store::HasMosaic() const { return fs::exists(MosaicPath()); }
std::string Store::PatchImagePath(int id) const {
  return (fs::path(dir_) / (PatchStem(id) + ".tif")).string();
}
std::string Store::PatchSidecarPath(int id) const {
  return (fs::path(dir_) / (PatchStem(id) + ".json")).string();
}

bool Store::LooksLikeStore(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec) && fs::is_regular_file(fs::path(path) / kManifest, ec);
}

Store Store::Create(const std::string& dir, const StoreOptions& options) {
  std::error_code ec;
  if (fs::exists(dir, ec)) {
    if (!fs::is_directory(dir, ec)) Fail(dir, "exists and is not a directory");
    if (!fs::is_empty(dir, ec))
      Fail(dir, LooksLikeStore(dir) ? "is already a store (open it, or choose a new name)"
                                    : "exists and is not empty; a new store needs a new or "
                                      "empty directory");
  }
  fs::create_directories(fs::path(dir) / "patches", ec);
  if (ec) Fail(dir, "cannot create the store directory: " + ec.message());
  Store s;
  s.dir_ = dir;
  s.state_->camera = options.camera;
  s.state_->crs = options.crs;
  std::lock_guard<std::mutex> lock(s.state_->mutex);
  s.WriteManifestLocked();
  return s;
}

void Store::Reload() {
  const Store fresh = Open(dir_);
  std::lock_guard<std::mutex> lock(state_->mutex);
  state_->camera = fresh.state_->camera;
  state_->crs = fresh.state_->crs;
  state_->patches = fresh.state_->patches;
  state_->global = fresh.state_->global;
  state_->extra = fresh.state_->extra;
}

Store Store::Open(const std::string& dir) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) Fail(dir, "no such store");
  if (!fs::is_directory(dir, ec)) Fail(dir, "is a file, not a store directory");
  const std::string manifest = (fs::path(dir) / kManifest).string();
  if (!fs::exists(manifest, ec)) Fail(dir, "is not a rolamos store (no store.json)");
  json j = json::parse(ReadSmallFile(manifest), nullptr, false);
  if (j.is_discarded()) Fail(manifest, "is not valid JSON");
  if (!j.is_object()) Fail(manifest, "must hold a JSON object");
  if (j.value("format", "") != kStoreFormat)
    Fail(manifest, "field \"format\" must be \"" + std::string(kStoreFormat) + "\"");
  if (!j.contains("version") || !j["version"].is_number_integer())
    Fail(manifest, "field \"version\" must be an integer");
  const int version = j["version"].get<int>();
  if (version < 1 || version > kStoreVersion)
    Fail(manifest, "store format version " + std::to_string(version) +
                       " is not readable by rolamos " ROLAMOS_VERSION_STRING " (reads 1.." +
                       std::to_string(kStoreVersion) + ")");
  Store s;
  s.dir_ = dir;
  s.state_->camera = j.value("camera", json(nullptr));
  if (j.contains("crs") && j["crs"].is_string()) s.state_->crs = j["crs"].get<std::string>();
  if (!j.contains("patches") || !j["patches"].is_array())
    Fail(manifest, "field \"patches\" must be an array");
  for (size_t i = 0; i < j["patches"].size(); ++i) {
    const json& p = j["patches"][i];
    const std::string where = manifest + ": patches[" + std::to_string(i) + "]";
    if (!p.is_object() || !p.contains("id") || !p["id"].is_number_integer() ||
        !p.contains("image") || !p["image"].is_string() || !p.contains("sidecar") ||
        !p["sidecar"].is_string())
      Fail(where, "needs an integer \"id\" and string \"image\" and \"sidecar\"");
    PatchEntry e{p["id"].get<int>(), p["image"].get<std::string>(),
                 p["sidecar"].get<std::string>()};
    CheckRelative(e.image, where);
    CheckRelative(e.sidecar, where);
    s.state_->patches.push_back(e);
  }
  if (!j.contains("global")) Fail(manifest, "missing field \"global\"");
  s.state_->global = GlobalFromJson(j["global"], manifest + ": global");
  for (auto it = j.begin(); it != j.end(); ++it) {
    static const char* known[] = {"format", "version", "created_by", "camera", "crs",
                                  "patches", "global", "mosaic"};
    bool is_known = false;
    for (const char* k : known) is_known = is_known || it.key() == k;
    if (!is_known) s.state_->extra[it.key()] = it.value();
  }
  return s;
}

void Store::WriteManifestLocked() const {
  json j = state_->extra;
  j["format"] = kStoreFormat;
  j["version"] = kStoreVersion;
  j["created_by"] = "rolamos " ROLAMOS_VERSION_STRING;
  j["camera"] = state_->camera;
  j["crs"] = state_->crs.empty() ? json(nullptr) : json(state_->crs);
  json patches = json::array();
  for (const auto& p : state_->patches)
    patches.push_back({{"id", p.id}, {"image", p.image}, {"sidecar", p.sidecar}});
  j["patches"] = patches;
  j["global"] = GlobalToJson(state_->global);
  j["mosaic"] = HasMosaic() ? json(kMosaic) : json(nullptr);
  WriteFileAtomic(ManifestPath(), j.dump(2) + "\n");
}

std::unique_ptr<StoreWriterLock> Store::LockForChange() {
  return LockStoreForChange(*this, "rolamos (a change to the manifest)");
}

int Store::NextPatchId() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  int next = 1;
  for (const auto& p : state_->patches) next = std::max(next, p.id + 1);
  return next;
}

void Store::CommitPatch(const PatchSidecar& sidecar) {
  const auto writer = LockForChange();
  std::lock_guard<std::mutex> lock(state_->mutex);
  const std::string image = PatchImagePath(sidecar.id);
  if (!fs::exists(image)) Fail(image, "patch image must be written before its sidecar is committed");
  for (const auto& p : state_->patches)
    if (p.id == sidecar.id) Fail(ManifestPath(), "patch " + std::to_string(sidecar.id) + " exists");
  WriteFileAtomic(PatchSidecarPath(sidecar.id), SidecarToJson(sidecar).dump(1) + "\n");
  state_->patches.push_back({sidecar.id, PatchStem(sidecar.id) + ".tif", PatchStem(sidecar.id) + ".json"});
  state_->global.n_patches = static_cast<int>(state_->patches.size());
  state_->global.n_images += sidecar.n_images;
  WriteManifestLocked();
}

void Store::UpdateSidecar(const PatchSidecar& sidecar) {
  const auto writer = LockForChange();
  std::lock_guard<std::mutex> lock(state_->mutex);
  for (const auto& p : state_->patches) {
    if (p.id == sidecar.id) {
      WriteFileAtomic((fs::path(dir_) / p.sidecar).string(), SidecarToJson(sidecar).dump(1) + "\n");
      return;
    }
  }
  Fail(ManifestPath(), "no patch " + std::to_string(sidecar.id));
}

void Store::ReplaceSidecars(const std::vector<PatchSidecar>& sidecars, const GlobalRecord& global) {
  const auto writer = LockForChange();
  std::lock_guard<std::mutex> lock(state_->mutex);
  // The next generation of sidecar names: patches/NNNNNN.vG.json.
  int generation = 0;
  for (const auto& p : state_->patches) {
    const std::string name = fs::path(p.sidecar).filename().string();
    const size_t v = name.rfind(".v");
    if (v != std::string::npos && name.size() > v + 7 && name.substr(name.size() - 5) == ".json")
      generation = std::max(generation, std::atoi(name.substr(v + 2, name.size() - 5 - v - 2).c_str()));
  }
  ++generation;
  std::vector<PatchEntry> entries = state_->patches;
  std::vector<std::string> old_files;
  for (const auto& s : sidecars) {
    auto it = std::find_if(entries.begin(), entries.end(), [&](const PatchEntry& e) { return e.id == s.id; });
    if (it == entries.end()) Fail(ManifestPath(), "no patch " + std::to_string(s.id));
    const std::string rel = PatchStem(s.id) + ".v" + std::to_string(generation) + ".json";
    WriteFileAtomic((fs::path(dir_) / rel).string(), SidecarToJson(s).dump(1) + "\n");
    old_files.push_back((fs::path(dir_) / it->sidecar).string());
    it->sidecar = rel;
  }
  const std::vector<PatchEntry> before = state_->patches;
  const GlobalRecord global_before = state_->global;
  state_->patches = entries;
  state_->global = global;
  state_->global.n_patches = static_cast<int>(entries.size());
  try {
    WriteManifestLocked();
  } catch (...) {
    state_->patches = before;
    state_->global = global_before;
    throw;
  }
  for (const auto& f : old_files) {
    std::error_code ec;
    fs::remove(f, ec);  // an old sidecar left behind is harmless: the manifest no longer names it
  }
}

std::vector<PatchEntry> Store::patches() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  return state_->patches;
}

PatchSidecar Store::ReadSidecar(int id) const {
  std::string path;
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    for (const auto& p : state_->patches)
      if (p.id == id) path = (fs::path(dir_) / p.sidecar).string();
  }
  if (path.empty()) Fail(ManifestPath(), "no patch " + std::to_string(id));
  if (!fs::exists(path)) Fail(path, "sidecar of patch " + std::to_string(id) + " is missing");
  PatchSidecar s = ParseSidecar(ReadSmallFile(path), path);
  if (s.id != id) Fail(path, "says it is patch " + std::to_string(s.id) + ", the manifest says " +
                                 std::to_string(id));
  return s;
}

GlobalRecord Store::global() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  return state_->global;
}

void Store::SetGlobal(const GlobalRecord& global) {
  const auto writer = LockForChange();
  std::lock_guard<std::mutex> lock(state_->mutex);
  state_->global = global;
  WriteManifestLocked();
}

nlohmann::json Store::camera() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  return state_->camera;
}

std::string Store::crs() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  return state_->crs;
}

std::vector<ExportEntry> Store::exports() const {
  std::lock_guard<std::mutex> lock(state_->mutex);
  std::vector<ExportEntry> out;
  const json& list = state_->extra.value("exports", json::array());
  if (!list.is_array()) return out;
  for (const json& e : list) {
    if (!e.is_object() || !e.contains("path") || !e["path"].is_string()) continue;
    ExportEntry x{e["path"].get<std::string>(), e.value("kind", "")};
    try {
      CheckRelative(x.path, ManifestPath() + ": exports");
    } catch (const Error&) {
      continue;  // a path leaving the store is never handed out
    }
    out.push_back(std::move(x));
  }
  return out;
}

void Store::RecordExport(const ExportEntry& entry) {
  CheckRelative(entry.path, ManifestPath() + ": exports");
  if (!fs::exists(fs::path(dir_) / entry.path)) Fail((fs::path(dir_) / entry.path).string(), "is not there to record");
  const auto writer = LockForChange();
  std::lock_guard<std::mutex> lock(state_->mutex);
  json list = state_->extra.value("exports", json::array());
  if (!list.is_array()) list = json::array();
  json kept = json::array();
  for (const json& e : list)
    if (!(e.is_object() && e.value("path", "") == entry.path)) kept.push_back(e);
  kept.push_back({{"path", entry.path}, {"kind", entry.kind}});
  state_->extra["exports"] = kept;
  WriteManifestLocked();
}

std::string Store::ImagePath(int patch) const {
  if (patch == 0) {
    if (!HasMosaic()) Fail(dir_, "has no global mosaic yet: run `rolamos compose` first, or choose a patch");
    return MosaicPath();
  }
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    for (const auto& p : state_->patches)
      if (p.id == patch) return (fs::path(dir_) / p.image).string();
  }
  Fail(dir_, "has no patch " + std::to_string(patch));
}

}  // namespace rolamos
