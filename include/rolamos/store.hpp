// The map store: a directory with store.json, patches/NNNNNN.{tif,json} and mosaic.tif.
// The format is a public contract (docs/store-format.md, version 1). Every write goes to a
// temporary name and is renamed into place; store.json is written last, so a store that was
// killed mid-write still opens and lists exactly the patches that were complete.
#pragma once

#include <array>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "rolamos/georef_io.hpp"

namespace rolamos {

inline constexpr const char* kStoreFormat = "rolamos-store";
inline constexpr int kStoreVersion = 1;

using Homography = std::array<double, 9>;  // row-major, source pixel -> target level-0 pixel
Homography IdentityHomography();

struct Egomotion {
  std::array<double, 9> R{};
  std::array<double, 3> t{};
  std::array<double, 3> n{};
};

struct FrameRecord {
  int index = 0;
  std::string source;
  Homography frame_to_patch = IdentityHomography();
  std::optional<Egomotion> egomotion;
  int matches = 0;
  int inliers = 0;
  double ecc = 0.0;
  std::string status = "stitched";
  // Optional fields (docs/store-format.md, "added fields"); absent when not written.
  std::optional<double> bilateral_error;       // mean bilateral epipolar error, pixels
  std::optional<double> ecc_shift_px;          // how far ECC moved the corners, pixels
  std::optional<Homography> frame_to_global;   // the aligned placement (rolamos align)
  // What align says of that placement: the RMS transfer error of the frame's edges, how far it may
  // be from where the map puts it (pixels, roughly 1 sigma), how many edges hold it, and whether it
  // sits far off its own edges even after being placed again (then it is not to be trusted).
  std::optional<double> residual_px;
  std::optional<double> uncertainty_px;
  std::optional<int> align_edges;
  std::optional<bool> placement_doubtful;
  // How the engine placed it when not simply against the frame before: "keyframe" (an earlier
  // frame of the patch), "patch_mosaic" (the patch image around the predicted place) or
  // "second_chance" (after being rejected, against a later frame).
  std::optional<std::string> registered_by;
  std::optional<bool> doubtful;        // weakly supported, kept because the motion model agreed
  std::optional<int> patch_frames;     // frames of the patch it was fitted against (with previous)
  // Absent (older stores) or true: a keyframe, adjusted with the patch's others (and blended
  // unless `blended` says otherwise). false: followed between keyframes and placed, not blended;
  // `placed_from` is the keyframe it was followed from.
  std::optional<bool> keyframe;
  std::optional<int> placed_from;
  // Absent or true: a keyframe's features were found and stored (when it had any). false: a
  // keyframe the engine linked by its tracks only, its ground described by its neighbours; its
  // frame is never read again to describe it.
  std::optional<bool> described;
  // Absent or true: a keyframe's pixels are blended into the patch image. false: a keyframe
  // adjusted with the others and placed (compose and align use it as any keyframe) whose pixels
  // are in the patch image only through the blended keyframes around it.
  std::optional<bool> blended;
  bool is_keyframe() const { return keyframe.value_or(true); }
  bool is_blended() const { return is_keyframe() && blended.value_or(true); }
  bool is_described() const { return is_keyframe() && described.value_or(true); }
  nlohmann::json extra = nlohmann::json::object();  // fields added by later versions, kept as read
};

struct RejectedFrame {
  int index = 0;
  std::string source;
  std::string reason;
};

// How a patch joins an earlier one: the engine's link when the pixel budget closed the previous
// patch, or compose's place recognition after tracking was lost.
struct PatchLink {
  int previous_patch = 0;
  Homography to_previous = IdentityHomography();  // this patch's pixels -> previous patch's pixels
  std::string method;                             // "" (the engine's) or "place_recognition"
  std::optional<int> inliers;                     // homography inliers, for place recognition
};

// One patch's sidecar, after Table I of the paper, with the documented optional fields typed.
struct PatchSidecar {
  int id = 0;
  std::array<long long, 2> size{0, 0};
  int n_images = 0;
  std::array<double, 2> offset{0, 0};
  Homography first_homography = IdentityHomography();
  Homography last_homography = IdentityHomography();
  std::optional<Homography> patch_to_global;
  std::vector<FrameRecord> frames;
  std::vector<RejectedFrame> rejected;
  std::optional<PatchLink> link;
  std::optional<long long> pixel_budget;              // the budget it was built under, pixels
  std::optional<std::array<int, 2>> frame_size;       // width, height of the rectified frames
  // Their pinhole camera matrix (after undistortion: a calibration's rectified one, or the field
  // of view's), as the engine took it; the adjustment's focal length is in `extra["adjustment"]`.
  std::optional<Homography> frame_camera_matrix;
  std::optional<Homography> patch_to_global_online;   // the online placement, kept by align
  std::optional<bool> aligned;                        // patch_to_global is the aligned placement
  std::optional<std::string> closed_by;               // "pixel_budget", "lost_tracking" or "end"
  // The frames' links and features for the global map (relative to the store), when written.
  std::optional<std::string> frame_links, frame_features;
  std::optional<int> component;                       // the part of the map it is in (align)
  nlohmann::json extra = nlohmann::json::object();    // fields added by later versions, kept as read
};

// The most matched pixels the engine keeps of a link in `frame_links` (48 in stores written before
// session 53; readers take any number), spread over the link's first frame. `align` fits each edge
// to as many (AlignOptions::pairs_per_edge): the pixels followed from frame to frame fit a link's
// homography better the more there are (bench/RESULTS.md, session 53).
inline constexpr int kMaxStoredLinkPairs = 192;

// The global record of Table I.
struct GlobalRecord {
  std::array<long long, 2> size{0, 0};
  std::array<double, 2> offset{0, 0};
  int n_images = 0;
  int n_patches = 0;
  double scale = 1.0;
  std::optional<Georef> georef;  // written as "crs" and "geotransform"
};

// JSON <-> records. Parsing validates every field and throws Error("<where>: <problem>").
nlohmann::json SidecarToJson(const PatchSidecar& sidecar);
PatchSidecar SidecarFromJson(const nlohmann::json& j, const std::string& where);
PatchSidecar ParseSidecar(const std::string& text, const std::string& where);
nlohmann::json GlobalToJson(const GlobalRecord& global);
GlobalRecord GlobalFromJson(const nlohmann::json& j, const std::string& where);

struct StoreOptions {
  nlohmann::json camera = nullptr;  // calibration the engine used, if any
  std::string crs;                  // the survey's CRS (WKT) when known
};

// A file exported into the store (a Cloud Optimized GeoTIFF `rolamos export --cog` wrote inside
// it): `rolamos serve` hands out exactly these, by name, with range requests.
struct ExportEntry {
  std::string path;  // relative to the store
  std::string kind;  // "cog"
};

struct PatchEntry {
  int id = 0;
  std::string image;    // relative to the store
  std::string sidecar;  // relative to the store
};

// A handle: copies share one manifest state (the engine's background writer and the caller see
// the same patches), and every method is safe to call from several threads.
class StoreWriterLock;

class Store {
 public:
  // Creates a new store; refuses a path that exists and is not an empty directory.
  static Store Create(const std::string& dir, const StoreOptions& options = {});
  // Opens an existing store; throws Error naming the file and the problem.
  static Store Open(const std::string& dir);
  static bool LooksLikeStore(const std::string& path);
  // Reads the manifest again into this handle and its copies: what another process committed
  // since it was opened (a writer that holds the store's writer lock starts from it).
  void Reload();

  const std::string& dir() const { return dir_; }
  std::string ManifestPath() const;
  std::string MosaicPath() const;
  bool HasMosaic() const;

  // Where the image of patch `id` goes; write it (PyramidTiffWriter is atomic), then CommitPatch.
  std::string PatchImagePath(int id) const;
  std::string PatchSidecarPath(int id) const;
  int NextPatchId() const;
  // Writes the sidecar, then the manifest. The image must already be in place.
  void CommitPatch(const PatchSidecar& sidecar);
  // Rewrites the sidecar of a committed patch (global alignment updates it).
  void UpdateSidecar(const PatchSidecar& sidecar);
  // Replaces the sidecars of several patches (and the global record) as one change: the new
  // sidecars are written under new names, then the manifest switches to them in one atomic
  // rename, then the old files go. Killed at any point, the store holds either every old sidecar
  // or every new one.
  void ReplaceSidecars(const std::vector<PatchSidecar>& sidecars, const GlobalRecord& global);

  std::vector<PatchEntry> patches() const;
  // One image of the store, as readers name it: patch `patch` (> 0) or the global mosaic (0).
  // Throws Error naming the store when it has no such patch, or no mosaic yet.
  std::string ImagePath(int patch) const;
  PatchSidecar ReadSidecar(int id) const;

  GlobalRecord global() const;
  void SetGlobal(const GlobalRecord& global);
  nlohmann::json camera() const;
  std::string crs() const;
  // The files exported into the store (manifest field "exports"), oldest first.
  std::vector<ExportEntry> exports() const;
  // Records `entry` (replacing one of the same path); the file must be in place, inside the store.
  void RecordExport(const ExportEntry& entry);

 private:
  struct State {
    std::mutex mutex;
    nlohmann::json camera = nullptr;
    std::string crs;
    std::vector<PatchEntry> patches;
    GlobalRecord global;
    nlohmann::json extra = nlohmann::json::object();
    int writer_locks = 0;  // StoreWriterLocks held through this handle (src/store/writer_lock.h)
  };
  friend class StoreWriterLock;
  Store() = default;
  void WriteManifestLocked() const;
  // Before a change to the manifest or a sidecar: where the store's writer lock is not held
  // through this handle, takes it for the change and reads the manifest again, so that
  // the change is made to what the store holds now (not to what this handle read when it opened)
  // and is refused, naming the writer, while an engine, align or compose writes the store.
  std::unique_ptr<StoreWriterLock> LockForChange();

  std::string dir_;
  std::shared_ptr<State> state_ = std::make_shared<State>();
};

}  // namespace rolamos
