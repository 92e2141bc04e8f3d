#include "rolamos/store.hpp"

#include <cstdio>
#include <filesystem>

#include "rolamos/error.hpp"
#include "rolamos/version.hpp"
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
  s.camera_ = options.camera;
  s.crs_ = options.crs;
  std::lock_guard<std::mutex> lock(*s.mutex_);
  s.WriteManifestLocked();
  return s;
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
  s.camera_ = j.value("camera", json(nullptr));
  if (j.contains("crs") && j["crs"].is_string()) s.crs_ = j["crs"].get<std::string>();
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
    s.patches_.push_back(e);
  }
  if (!j.contains("global")) Fail(manifest, "missing field \"global\"");
  s.global_ = GlobalFromJson(j["global"], manifest + ": global");
  s.extra_ = json::object();
  for (auto it = j.begin(); it != j.end(); ++it) {
    static const char* known[] = {"format", "version", "created_by", "camera", "crs",
                                  "patches", "global", "mosaic"};
    bool is_known = false;
    for (const char* k : known) is_known = is_known || it.key() == k;
    if (!is_known) s.extra_[it.key()] = it.value();
  }
  return s;
}

void Store::WriteManifestLocked() const {
  json j = extra_;
  j["format"] = kStoreFormat;
  j["version"] = kStoreVersion;
  j["created_by"] = "rolamos " ROLAMOS_VERSION_STRING;
  j["camera"] = camera_;
  j["crs"] = crs_.empty() ? json(nullptr) : json(crs_);
  json patches = json::array();
  for (const auto& p : patches_)
    patches.push_back({{"id", p.id}, {"image", p.image}, {"sidecar", p.sidecar}});
  j["patches"] = patches;
  j["global"] = GlobalToJson(global_);
  j["mosaic"] = HasMosaic() ? json(kMosaic) : json(nullptr);
  WriteFileAtomic(ManifestPath(), j.dump(2) + "\n");
}

int Store::NextPatchId() const {
  std::lock_guard<std::mutex> lock(*mutex_);
  int next = 1;
  for (const auto& p : patches_) next = std::max(next, p.id + 1);
  return next;
}

void Store::CommitPatch(const PatchSidecar& sidecar) {
  std::lock_guard<std::mutex> lock(*mutex_);
  const std::string image = PatchImagePath(sidecar.id);
  if (!fs::exists(image)) Fail(image, "patch image must be written before its sidecar is committed");
  for (const auto& p : patches_)
    if (p.id == sidecar.id) Fail(ManifestPath(), "patch " + std::to_string(sidecar.id) + " exists");
  WriteFileAtomic(PatchSidecarPath(sidecar.id), SidecarToJson(sidecar).dump(1) + "\n");
  patches_.push_back({sidecar.id, PatchStem(sidecar.id) + ".tif", PatchStem(sidecar.id) + ".json"});
  global_.n_patches = static_cast<int>(patches_.size());
  global_.n_images += sidecar.n_images;
  WriteManifestLocked();
}

void Store::UpdateSidecar(const PatchSidecar& sidecar) {
  std::lock_guard<std::mutex> lock(*mutex_);
  for (const auto& p : patches_) {
    if (p.id == sidecar.id) {
      WriteFileAtomic((fs::path(dir_) / p.sidecar).string(), SidecarToJson(sidecar).dump(1) + "\n");
      return;
    }
  }
  Fail(ManifestPath(), "no patch " + std::to_string(sidecar.id));
}

std::vector<PatchEntry> Store::patches() const {
  std::lock_guard<std::mutex> lock(*mutex_);
  return patches_;
}

PatchSidecar Store::ReadSidecar(int id) const {
  std::string path;
  {
    std::lock_guard<std::mutex> lock(*mutex_);
    for (const auto& p : patches_)
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
  std::lock_guard<std::mutex> lock(*mutex_);
  return global_;
}

void Store::SetGlobal(const GlobalRecord& global) {
  std::lock_guard<std::mutex> lock(*mutex_);
  global_ = global;
  WriteManifestLocked();
}

nlohmann::json Store::camera() const {
  std::lock_guard<std::mutex> lock(*mutex_);
  return camera_;
}

std::string Store::crs() const {
  std::lock_guard<std::mutex> lock(*mutex_);
  return crs_;
}

}  // namespace rolamos
