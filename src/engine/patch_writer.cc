#include "engine/patch_writer.h"

#include <limits>

#include "util/homography.h"

namespace rolamos {

PatchSidecar AssemblePatchSidecar(int id, const cv::Rect& rect, std::vector<FrameRecord> frames,
                                  std::vector<RejectedFrame> rejected, const std::optional<PatchLink>& link,
                                  long long pixel_budget, cv::Size frame_size) {
  const cv::Matx33d T(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1);
  PatchSidecar s;
  s.id = id;
  s.size = {rect.width, rect.height};
  s.n_images = static_cast<int>(frames.size());
  s.offset = {double(-rect.x), double(-rect.y)};
  for (auto& f : frames) f.frame_to_patch = ToArray9(T * ToMatx(f.frame_to_patch));
  if (!frames.empty()) {
    s.first_homography = frames.front().frame_to_patch;
    s.last_homography = frames.back().frame_to_patch;
  }
  s.frames = std::move(frames);
  s.rejected = std::move(rejected);
  if (link) {
    s.link = *link;
    s.link->to_previous = ToArray9(ToMatx(link->to_previous) * T.inv());
  }
  s.pixel_budget = pixel_budget;
  s.frame_size = std::array<int, 2>{frame_size.width, frame_size.height};
  return s;
}

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
  if (!job.images.empty()) {
    auto canvas = std::make_unique<PatchCanvas>(std::numeric_limits<long long>::max());
    for (size_t i = 0; i < job.images.size(); ++i) {
      canvas->Add(job.images[i], *job.weights, job.placements[i]);
      job.images[i].release();
    }
    job.canvas = std::move(canvas);
  }
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
