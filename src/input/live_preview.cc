#include "input/live_preview.h"

#include <chrono>
#include <cstdio>
#include <filesystem>

#include <nlohmann/json.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiff_writer.hpp"
#include "util/clock.h"
#include "util/files.h"
#include "util/homography.h"

namespace rolamos {

namespace {

constexpr int kKeep = 3;  // versions kept on disk: a server may still read the one before

std::string VersionName(long long v) {
  char name[40];
  std::snprintf(name, sizeof name, "preview-%06lld.tif", v);
  return name;
}

nlohmann::json Points(const std::vector<cv::Point2d>& points) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& p : points) out.push_back({std::round(p.x * 100) / 100, std::round(p.y * 100) / 100});
  return out;
}

}  // namespace

LivePreviewWriter::LivePreviewWriter(std::string store_dir) : dir_(std::move(store_dir) + "/live") {
  std::error_code ec;
  std::filesystem::create_directories(dir_, ec);
  // Versions left by an earlier run are not this run's.
  for (const auto& e : std::filesystem::directory_iterator(dir_, ec))
    if (e.path().filename().string().rfind("preview-", 0) == 0) std::filesystem::remove(e.path(), ec);
  thread_ = std::thread([this] { Run(); });
}

LivePreviewWriter::~LivePreviewWriter() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    closing_ = true;
  }
  changed_.notify_all();
  thread_.join();
  // The run is over: its patches are written, nothing is open.
  try {
    Write(LivePreview{}, 0);
  } catch (...) {
  }
}

void LivePreviewWriter::Offer(LivePreview preview) {
  if (!preview.image.empty()) imaged_patch_ = preview.patch_id;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // An image waiting to be written is kept when only the track is newer.
    if (pending_ && !pending_->image.empty() && preview.image.empty() && pending_->patch_id == preview.patch_id) {
      preview.image = pending_->image;
      preview.patch_to_image = pending_->patch_to_image;
    } else if (!preview.image.empty()) {
      pending_image_frames_ = preview.frames;
    }
    pending_ = std::move(preview);
  }
  changed_.notify_all();
}

std::string LivePreviewWriter::problem() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return problem_;
}

void LivePreviewWriter::Run() {
  for (;;) {
    LivePreview p;
    int image_frames = 0;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [&] { return closing_ || pending_; });
      if (!pending_) return;
      p = std::move(*pending_);
      pending_.reset();
      image_frames = pending_image_frames_;
    }
    try {
      Write(p, image_frames);
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (problem_.empty()) problem_ = e.what();
    }
    // At most four writes a second; what is offered meanwhile waits, the newest replacing the rest.
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait_for(lock, std::chrono::milliseconds(250), [&] { return closing_; });
  }
}

void LivePreviewWriter::Write(const LivePreview& p, int image_frames) {
  nlohmann::json j = {{"format", "rolamos-live-preview"}, {"version", 1}, {"patch", p.patch_id},
                      {"updated", UnixNow()}};
  if (p.patch_id > 0 && !p.image.empty()) {
    const long long v = ++version_;
    TiffWriteOptions o;
    // The alpha (where the patch has no data yet) as a mask: a fifth of WebP's encoding time,
    // which the engine's cores would otherwise give up every preview.
    o.compression = Compression::kJpegMask;
    o.quality = 80;
    o.threads = 1;  // the engine has the cores
    WritePyramidTiff(dir_ + "/" + VersionName(v), p.image, o);
    written_ = {p.patch_id, "live/" + VersionName(v), p.image.cols, p.image.rows, image_frames, p.patch_to_image};
  }
  if (p.patch_id > 0 && written_.patch == p.patch_id) {
    j["image"] = written_.image;
    j["width"] = written_.width;
    j["height"] = written_.height;
    j["patch_to_image"] = ToArray9(written_.patch_to_image);
    j["image_frames"] = written_.frames;
  }
  if (p.patch_id > 0) {
    j["frames"] = p.frames;
    j["last_frame"] = {{"index", p.last_index}, {"source", p.last_source}};
    j["track"] = Points(p.track);
    j["track_frames"] = p.track_frames;
    j["frame_size"] = {p.frame_size.width, p.frame_size.height};
    j["footprint"] = Points(p.footprint);
    j["previous_patch"] = p.previous_patch > 0 ? nlohmann::json(p.previous_patch) : nlohmann::json(nullptr);
    if (p.previous_patch > 0) j["to_previous_first"] = ToArray9(p.to_previous_first);
  }
  WriteFileAtomic(dir_ + "/preview.json", j.dump(), /*durable=*/false);
  std::error_code ec;
  for (long long old = version_ - kKeep; old > 0 && old > version_ - kKeep - 4; --old)
    std::filesystem::remove(dir_ + "/" + VersionName(old), ec);
  if (p.patch_id == 0)
    for (long long old = version_; old > version_ - kKeep && old > 0; --old)
      std::filesystem::remove(dir_ + "/" + VersionName(old), ec);
}

}  // namespace rolamos
