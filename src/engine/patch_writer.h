// Writes closed patches to the store in a background thread, so the pipeline does not stall.
// At most one patch waits: Submit blocks while the previous one is still being written, which
// bounds memory at two canvases whatever the survey length.
#pragma once

#include <functional>
#include <future>
#include <memory>

#include "engine/patch_canvas.h"
#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct PatchJob {
  std::unique_ptr<PatchCanvas> canvas;
  cv::Rect data_rect;  // patch coordinates of the image to write
  PatchSidecar sidecar;
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

 private:
  void Write(PatchJob& job);

  Store store_;
  TiffWriteOptions options_;
  std::future<void> pending_;
  std::function<void(const PatchSidecar&)> on_patch_;
  int written_ = 0;
};

}  // namespace rolamos
