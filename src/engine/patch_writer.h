// Closes patches in a background thread, so the engine goes on with the next frames: the patch's
// keyframes are adjusted together as cameras over the seafloor plane, every other frame is placed
// from the keyframe it was followed from, the keyframes are blended at full resolution with their
// exposures matched, and the image, its links and features and its sidecar are written. One patch
// is written while at most one more waits: memory stays at two patches' keyframes.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "engine/keyframe_job.h"
#include "engine/patch_adjustment.h"
#include "engine/patch_canvas.h"
#include "store/frame_data.h"
#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"
#include "util/task_pool.h"

namespace rolamos {

// The sidecar of a closed patch: the frames' placements (and the link to the previous patch),
// given in the patch's first-frame coordinates, are moved to the pixel grid of the image, which
// covers `rect` of those coordinates.
PatchSidecar AssemblePatchSidecar(int id, const cv::Rect& rect, std::vector<FrameRecord> frames,
                                  std::vector<RejectedFrame> rejected, const std::optional<PatchLink>& link,
                                  long long pixel_budget, cv::Size frame_size);

// A frame's features as the store keeps them: at most `count`, spread over the frame.
StoredFeatures ToStored(int index, const Features& f, cv::Size frame, int count = kStoredFeatures);

// The frame that opens the next patch when the pixel budget closed this one: adjusted with this
// patch's keyframes (not blended) to tie the two patches together.
struct ClosingFrame {
  int index = 0;
  cv::Matx33d to_patch;
  std::vector<FrameLink> links;
};

// A closed patch, as the engine hands it over.
struct PatchJob {
  int id = 0;
  int next_id = 0;  // the patch the closing frame opens
  std::string closed_by;
  cv::Size frame_size;
  long long pixel_budget = 0;
  double focal = 0;
  cv::Matx33d camera = cv::Matx33d::eye();  // the frames' pinhole camera, as assumed
  // Every placed frame, online frame -> first-frame coordinates; the frames that are not
  // keyframes have `placed_from`.
  std::vector<FrameRecord> frames;
  std::vector<RejectedFrame> rejected;
  // How the patch joins the one before (closed by its pixel budget): `to_previous` is taken from
  // where that patch's closing frame ended up.
  std::optional<PatchLink> link;
  std::vector<std::pair<int, KeyframeFuture>> products;  // per keyframe (its index)
  std::vector<FrameLink> links;  // between keyframes, found online (tracks)
  std::optional<ClosingFrame> closing;
  PatchAdjustmentOptions adjust;
  std::shared_ptr<const FeatherCode> weights;
  // Colour: per-pixel multiplier of every frame (lighting and water colour; empty = none), and
  // whether each frame's exposure is matched to its neighbours'.
  cv::Mat colour;
  bool exposure = false;
  double exposure_prior = 0.05;
};

class PatchWriter {
 public:
  PatchWriter(Store store, const TiffWriteOptions& options);
  ~PatchWriter();
  // Queues a patch (blocks while one is written and another waits).
  void Submit(PatchJob job);
  // Waits for the patches queued; rethrows a writer error.
  void Wait();
  void OnPatch(std::function<void(const PatchSidecar&)> f) { on_patch_ = std::move(f); }
  int written() const { return written_; }
  // Patches whose placements the adjustment replaced; the others, with the reason.
  int adjusted() const { return adjusted_; }
  struct Unadjusted {
    int patch = 0;
    PatchAdjustment::Miss miss = PatchAdjustment::Miss::kNone;
    std::string why;
  };
  std::vector<Unadjusted> unadjusted() const {
    std::lock_guard<std::mutex> lock(unadjusted_mutex_);
    return unadjusted_;
  }
  // Time spent closing patches (adjustment, blending, writing), seconds, and of it the adjustment.
  double busy_seconds() const { return busy_ns_.load() * 1e-9; }
  double adjust_seconds() const { return adjust_ns_.load() * 1e-9; }
  // CPU time the image encoders' threads spent on the patches' tiles.
  double encode_seconds() const { return encode_ns_.load() * 1e-9; }

 private:
  void Write(PatchJob& job);

  Store store_;
  TiffWriteOptions options_;
  std::function<void(const PatchSidecar&)> on_patch_;
  std::atomic<int> written_{0};
  std::atomic<int> adjusted_{0};
  mutable std::mutex unadjusted_mutex_;
  std::vector<Unadjusted> unadjusted_;
  std::atomic<long long> busy_ns_{0}, adjust_ns_{0}, encode_ns_{0};
  // Where the last patch's closing frame is in its image: the next patch's link.
  std::optional<cv::Matx33d> closing_to_image_;
  TaskPool pool_{1, 1};
};

}  // namespace rolamos
