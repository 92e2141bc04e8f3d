#include "engine/patch_writer.h"

namespace rolamos {

PatchWriter::~PatchWriter() {
  try {
    Wait();
  } catch (...) {
  }
}

void PatchWriter::Wait() {
  if (pending_.valid()) pending_.get();
}

void PatchWriter::Submit(PatchJob job) {
  Wait();
  auto shared = std::make_shared<PatchJob>(std::move(job));
  pending_ = std::async(std::launch::async, [this, shared] { Write(*shared); });
}

void PatchWriter::Write(PatchJob& job) {
  PixelLayout layout;
  layout.width = job.data_rect.width;
  layout.height = job.data_rect.height;
  layout.channels = 4;  // alpha marks where the patch has data
  PyramidTiffWriter writer(store_.PatchImagePath(job.sidecar.id), layout, options_);
  for (int y = 0; y < job.data_rect.height; y += writer.band_height()) {
    const int rows = std::min(writer.band_height(), job.data_rect.height - y);
    writer.WriteBand(job.canvas->Render(
        cv::Rect(job.data_rect.x, job.data_rect.y + y, job.data_rect.width, rows)));
  }
  writer.Finish();
  job.canvas.reset();  // free the canvas before committing
  store_.CommitPatch(job.sidecar);
  ++written_;
  if (on_patch_) on_patch_(job.sidecar);
}

}  // namespace rolamos
