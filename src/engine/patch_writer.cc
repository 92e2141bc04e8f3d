#include "engine/patch_writer.h"

#include <opencv2/imgproc.hpp>

#include "util/exposure_gains.h"

#include <chrono>
#include <filesystem>
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
  const auto start = std::chrono::steady_clock::now();
  // The temporal term of the paper's filter (each frame averaged with the one stitched before it,
  // brought in by their final placements), then blending at full resolution.
  auto canvas = std::make_unique<PatchCanvas>(std::numeric_limits<long long>::max(), 1.0, false);
  // Exposure gains from the corrected frames at 1/8 resolution (where they overlap on the patch).
  std::vector<double> gains(job.images.size(), 1.0);
  const bool colour = !job.colour.empty() || job.exposure;
  if (job.exposure) {
    constexpr double kGainScale = 0.125;
    cv::Mat small_colour;
    if (!job.colour.empty()) cv::resize(job.colour, small_colour, cv::Size(), kGainScale, kGainScale, cv::INTER_AREA);
    std::vector<cv::Mat> small(job.images.size());
    for (size_t i = 0; i < job.images.size(); ++i) {
      cv::resize(job.images[i], small[i], cv::Size(), kGainScale, kGainScale, cv::INTER_AREA);
      small[i].convertTo(small[i], CV_32F);
      if (!small_colour.empty() && small_colour.size() == small[i].size()) small[i] = small[i].mul(small_colour);
    }
    gains = SolveExposureGains(small, kGainScale, job.placements, job.exposure_prior);
  }
  cv::Mat previous;
  for (size_t i = 0; i < job.images.size(); ++i) {
    cv::Mat filtered = job.images[i];
    if (job.temporal && !previous.empty())
      filtered = job.temporal->Temporal(job.images[i], previous, job.placements[i - 1].inv() * job.placements[i]);
    previous = filtered;
    if (colour) {
      // Corrected in float and blended in 16 bits: no clipping before the patch is rendered.
      cv::Mat f;
      filtered.convertTo(f, CV_32F, gains[i] * PatchCanvas::kDeepScale);
      if (!job.colour.empty()) f = f.mul(job.colour);
      cv::Mat deep;
      f.convertTo(deep, CV_16U);
      canvas->Add(deep, *job.weights, job.placements[i]);
    } else {
      canvas->Add(filtered, *job.weights, job.placements[i]);
    }
    job.images[i].release();
  }
  PixelLayout layout;
  layout.width = job.data_rect.width;
  layout.height = job.data_rect.height;
  layout.channels = 4;  // alpha marks where the patch has data
  PyramidTiffWriter writer(store_.PatchImagePath(job.sidecar.id), layout, options_);
  for (int y = 0; y < job.data_rect.height; y += writer.band_height()) {
    const int rows = std::min(writer.band_height(), job.data_rect.height - y);
    writer.WriteBand(canvas->Render(
        cv::Rect(job.data_rect.x, job.data_rect.y + y, job.data_rect.width, rows)));
  }
  writer.Finish();
  canvas.reset();  // free the canvas before committing
  // Links and features first: a committed sidecar names only files that are there.
  const std::string stem = store_.PatchSidecarPath(job.sidecar.id).substr(0, store_.PatchSidecarPath(job.sidecar.id).size() - 5);
  const std::string rel = std::filesystem::path(stem).parent_path().filename().string() + "/" +
                          std::filesystem::path(stem).filename().string();
  if (!job.links.empty()) {
    WriteFrameLinks(stem + ".links.json", job.links);
    job.sidecar.frame_links = rel + ".links.json";
  }
  if (!job.features.empty()) {
    WriteFrameFeatures(stem + ".features", job.features);
    job.sidecar.frame_features = rel + ".features";
  }
  busy_ns_ += std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count();
  store_.CommitPatch(job.sidecar);
  ++written_;
  if (on_patch_) on_patch_(job.sidecar);
}

}  // namespace rolamos
