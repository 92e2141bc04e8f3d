// Writes closed patches to the store in a background thread, so the pipeline does not stall.
// At most one patch waits: Submit blocks while the previous one is still being written, which
// bounds memory at two canvases whatever the survey length.
#pragma once

#include <atomic>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <vector>

#include "engine/patch_canvas.h"
#include "engine/preprocess.h"
#include "store/frame_data.h"
#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

// The sidecar of a closed patch: the frames' placements (and the link to the previous patch),
// given in the patch's first-frame coordinates, are moved to the pixel grid of the image, which
// covers `rect` of those coordinates.
PatchSidecar AssemblePatchSidecar(int id, const cv::Rect& rect, std::vector<FrameRecord> frames,
                                  std::vector<RejectedFrame> rejected, const std::optional<PatchLink>& link,
                                  long long pixel_budget, cv::Size frame_size);

// A closed patch: its frames (BGR after the spatial filter, in the order they were stitched) and
// their final placements; the writer filters them in time, blends them at full resolution and
// writes the image, in its own thread.
struct PatchJob {
  cv::Rect data_rect;  // patch coordinates of the image to write
  PatchSidecar sidecar;
  std::vector<cv::Mat> images;
  std::vector<cv::Matx33d> placements;  // frame -> patch coordinates
  std::shared_ptr<const FeatherCode> weights;
  const Preprocessor* temporal = nullptr;  // the temporal filter, when on
  // Colour: per-pixel multiplier of every frame (lighting and water colour; empty = none), and
  // whether each frame's exposure is matched to its neighbours.
  cv::Mat colour;
  bool exposure = false;
  double exposure_prior = 0.05;
  // For the global map: the links found between the patch's frames, and their features.
  std::vector<StoredLink> links;
  std::vector<StoredFeatures> features;
};

class PatchWriter {
 public:
  PatchWriter(Store store, const TiffWriteOptions& options) : store_(std::move(store)), options_(options) {}
  ~PatchWriter();
  void Submit(PatchJob job);
  // Waits for the last patch; rethrows a writer error.
  void Wait();
  void OnPatch(std::function<void(const PatchSidecar&)> f) { on_patch_ = std::move(f); }
  int written() const { return written_; }
  // Time spent filtering, blending and writing patches, seconds (the writer's own thread).
  double busy_seconds() const { return busy_ns_.load() * 1e-9; }

 private:
  void Write(PatchJob& job);

  Store store_;
  TiffWriteOptions options_;
  std::future<void> pending_;
  std::function<void(const PatchSidecar&)> on_patch_;
  int written_ = 0;
  std::atomic<long long> busy_ns_{0};
};

}  // namespace rolamos
