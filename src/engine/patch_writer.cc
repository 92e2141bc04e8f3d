#include "engine/patch_writer.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <limits>
#include <map>
#include <set>

#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "util/cpu_time.h"
#include "util/exposure_gains.h"
#include "util/homography.h"

namespace rolamos {

namespace {

// Frames followed between two keyframes of the patch, placed where both put them, from the
// keyframes' placements in `keyframe_at`.
void PlaceBetween(PatchJob& job, const std::vector<FollowedBetween>& between,
                  const std::map<int, cv::Matx33d>& keyframe_at) {
  std::map<int, const FollowedBetween*> of;
  for (const auto& b : between)
    if (keyframe_at.count(b.before) && keyframe_at.count(b.after)) of[b.index] = &b;
  for (auto& f : job.frames) {
    auto it = of.find(f.index);
    if (f.is_keyframe() || it == of.end()) continue;
    const FollowedBetween& b = *it->second;
    const cv::Matx33d from_before = keyframe_at.at(b.before) * b.to_before;
    const cv::Matx33d from_after = keyframe_at.at(b.after) * b.to_after;
    f.frame_to_patch = ToArray9(BlendHomographies(from_before, from_after, b.weight_before, job.frame_size));
  }
}

// The patch's frames placed once more: keyframes adjusted together (with the closing frame),
// every other frame carried along from the keyframe it was followed from, or placed where the
// keyframes on both sides put it. Returns the adjustment; `frames` and `closing_to_patch` are
// updated.
PatchAdjustment PlaceFrames(PatchJob& job, const std::vector<FrameLink>& loop_links,
                            const std::vector<FollowedBetween>& between, cv::Matx33d* closing_to_patch) {
  std::vector<int> indices;
  std::vector<cv::Matx33d> online;
  std::map<int, cv::Matx33d> online_of;
  for (const auto& f : job.frames) {
    online_of[f.index] = ToMatx(f.frame_to_patch);
    if (!f.is_keyframe()) continue;
    indices.push_back(f.index);
    online.push_back(ToMatx(f.frame_to_patch));
  }
  std::vector<FrameLink> all = job.links;
  all.insert(all.end(), loop_links.begin(), loop_links.end());
  if (job.closing) {
    indices.push_back(job.closing->index);
    online.push_back(job.closing->to_patch);
    all.insert(all.end(), job.closing->links.begin(), job.closing->links.end());
  }
  if (job.closing) *closing_to_patch = job.closing->to_patch;
  PatchAdjustment adjusted;
  if (job.adjust.enabled) adjusted = AdjustPatch(indices, online, all, job.focal, job.frame_size, job.adjust);
  if (!adjusted.used) {
    PlaceBetween(job, between, online_of);
    return adjusted;
  }
  std::map<int, cv::Matx33d> adjusted_of;
  for (size_t i = 0; i < indices.size(); ++i) adjusted_of[indices[i]] = adjusted.frame_to_patch[i];
  for (auto& f : job.frames) {
    if (f.is_keyframe()) {
      f.frame_to_patch = ToArray9(adjusted_of[f.index]);
    } else if (f.placed_from && adjusted_of.count(*f.placed_from)) {
      const int k = *f.placed_from;
      f.frame_to_patch = ToArray9(adjusted_of[k] * online_of[k].inv() * online_of[f.index]);
    }
  }
  PlaceBetween(job, between, adjusted_of);
  if (job.closing) *closing_to_patch = adjusted.frame_to_patch.back();
  // This patch's coordinates are now the plane's: the link to the previous patch goes through
  // the first frame's adjusted pose.
  if (job.link) job.link->to_previous = ToArray9(ToMatx(job.link->to_previous) * adjusted.frame_to_patch[0].inv());
  return adjusted;
}

// A frame turned against the patch's rows has, in each band, the bounding box of a slanted strip
// to warp: often most of the frame. Interleaving it once for all its bands then costs less than
// band by band (three times the frames' pixels on turning surveys), though it holds 8 bytes a
// pixel until its last band instead of the 8-bit frame's 3.
constexpr double kInterleaveOnce = 1.5;

// The pixels of the frame that the bands of `rect` take, over the frame's own.
double SourceShare(const cv::Matx33d& placement, const cv::Rect& rect, int band_height, cv::Size frame) {
  double taken = 0;
  for (int y = rect.y; y < rect.y + rect.height; y += band_height) {
    const cv::Rect band(rect.x, y, rect.width, std::min(band_height, rect.y + rect.height - y));
    taken += PatchCanvas::SourceRect(placement, band, frame).area();
  }
  return taken / std::max(1, frame.area());
}

// The keyframes blended at full resolution, exposures matched, colour corrected in float and
// blended in 16 bits; written as the patch image covering `rect`. One band of the image at a
// time, from the rows of each frame that land in it: the writer holds a band's sums, not the
// patch's, whatever the patch's size (a patch adjusted out of its online bounds, a long lane).
TiffWriteStats BlendAndWrite(const PatchJob& job, std::vector<cv::Mat>& images,
                             const std::vector<cv::Matx33d>& placements, const cv::Rect& rect,
                             const std::string& path, const TiffWriteOptions& options) {
  std::vector<double> gains(images.size(), 1.0);
  const bool colour = !job.colour.empty() || job.exposure;
  if (job.exposure) {
    // Exposure gains from the corrected frames at 1/8 resolution (where they overlap on the patch).
    constexpr double kGainScale = 0.125;
    cv::Mat small_colour;
    if (!job.colour.empty()) cv::resize(job.colour, small_colour, cv::Size(), kGainScale, kGainScale, cv::INTER_AREA);
    std::vector<cv::Mat> small(images.size());
    for (size_t i = 0; i < images.size(); ++i) {
      ResizeArea(images[i], small[i], kGainScale);
      small[i].convertTo(small[i], CV_32F);
      if (!small_colour.empty() && small_colour.size() == small[i].size()) small[i] = small[i].mul(small_colour);
    }
    gains = SolveExposureGains(small, kGainScale, placements, job.exposure_prior);
  }
  std::vector<cv::Rect2d> bounds(images.size());
  for (size_t i = 0; i < images.size(); ++i) bounds[i] = PatchCanvas::FrameBounds(placements[i], images[i].size());
  PixelLayout layout;
  layout.width = rect.width;
  layout.height = rect.height;
  layout.channels = 4;  // alpha marks where the patch has data
  PyramidTiffWriter writer(path, layout, options);
  // A frame's colour and feather code, interleaved for the warp (corrected in float into 16 bits
  // when colour is on: no clipping before the patch is rendered).
  auto interleave = [&](size_t i, const cv::Rect& src) {
    if (colour)
      return PatchCanvas::InterleaveDeep(images[i](src), job.colour.empty() ? cv::Mat() : job.colour(src),
                                         gains[i] * PatchCanvas::kDeepScale, job.weights->code(src));
    return PatchCanvas::Interleave(images[i](src), job.weights->code(src));
  };
  // Which frames are interleaved once, at their first band (decided once, before the bands).
  std::vector<char> whole(images.size(), 0);
  for (size_t i = 0; i < images.size(); ++i)
    whole[i] = SourceShare(placements[i], rect, writer.band_height(), images[i].size()) > kInterleaveOnce;
  for (int y = 0; y < rect.height; y += writer.band_height()) {
    const cv::Rect band(rect.x, rect.y + y, rect.width, std::min(writer.band_height(), rect.height - y));
    PatchCanvas canvas(std::numeric_limits<long long>::max(), 1.0, false);
    for (size_t i = 0; i < images.size(); ++i) {
      if (images[i].empty() || (cv::Rect2d(band) & bounds[i]).empty()) continue;
      if (whole[i] && images[i].channels() == 3) images[i] = interleave(i, cv::Rect(cv::Point(), images[i].size()));
      const cv::Rect src = PatchCanvas::SourceRect(placements[i], band, images[i].size());
      if (src.empty()) continue;
      const cv::Matx33d part_to_patch = placements[i] * cv::Matx33d(1, 0, src.x, 0, 1, src.y, 0, 0, 1);
      canvas.AddInterleaved(whole[i] ? images[i](src) : interleave(i, src), job.weights->weight, part_to_patch, band);
      // A frame that ends in this band is not needed for the next.
      if (bounds[i].br().y + 1 < band.br().y) images[i].release();
    }
    writer.WriteBand(canvas.Render(band));
  }
  return writer.Finish();
}

}  // namespace

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

StoredFeatures ToStored(int index, const Features& f, cv::Size frame, int count) {
  StoredFeatures s;
  s.index = index;
  if (f.norm != cv::NORM_L2 || f.descriptors.cols != 128) return s;  // only SIFT goes to the store
  constexpr int kCells = 8;
  std::vector<std::vector<int>> cells(kCells * kCells);
  for (size_t i = 0; i < f.points.size(); ++i) {
    const int cx = std::clamp(int(f.points[i].x * kCells / std::max(1, frame.width)), 0, kCells - 1);
    const int cy = std::clamp(int(f.points[i].y * kCells / std::max(1, frame.height)), 0, kCells - 1);
    cells[size_t(cy * kCells + cx)].push_back(static_cast<int>(i));
  }
  std::vector<int> keep;
  for (size_t round = 0; static_cast<int>(keep.size()) < count; ++round) {
    bool any = false;
    for (const auto& c : cells) {
      if (round >= c.size() || static_cast<int>(keep.size()) >= count) continue;
      keep.push_back(c[round]);
      any = true;
    }
    if (!any) break;
  }
  s.descriptors = cv::Mat(static_cast<int>(keep.size()), 128, CV_8U);
  for (size_t k = 0; k < keep.size(); ++k) {
    s.points.push_back(f.points[size_t(keep[k])]);
    f.descriptors.row(keep[k]).convertTo(s.descriptors.row(static_cast<int>(k)), CV_8U);
  }
  return s;
}

PatchWriter::PatchWriter(Store store, const TiffWriteOptions& options) : store_(std::move(store)), options_(options) {}

PatchWriter::~PatchWriter() {
  try {
    Wait();
  } catch (...) {
  }
}

void PatchWriter::Wait() { pool_.Wait(); }

void PatchWriter::Submit(PatchJob job) {
  auto shared = std::make_shared<PatchJob>(std::move(job));
  pool_.Submit([this, shared] { Write(*shared); });
}

void PatchWriter::Write(PatchJob& job) {
  CpuLaps cpu;  // the writer's own CPU time (waits for keyframe jobs are not)
  // The keyframes' filtered images, features and loop closures (their jobs may still run).
  // In the order of the keyframes in `frames`.
  std::map<int, KeyframeFuture> product_of(job.products.begin(), job.products.end());
  job.products.clear();
  std::vector<cv::Mat> images;  // of the blended keyframes
  std::vector<std::shared_ptr<const Features>> features;
  std::vector<FrameLink> loop_links;
  std::vector<FollowedBetween> between;
  std::vector<int> key_indices;
  std::set<int> blended;
  for (const auto& f : job.frames) {
    if (!f.is_keyframe()) continue;
    auto it = product_of.find(f.index);
    if (it == product_of.end()) continue;
    const KeyframeProducts& k = it->second.get();
    if (!k.image.empty()) {
      images.push_back(k.image);
      blended.insert(f.index);
    }
    features.push_back(k.features);
    loop_links.insert(loop_links.end(), k.loop_links.begin(), k.loop_links.end());
    between.insert(between.end(), k.between.begin(), k.between.end());
    key_indices.push_back(f.index);
  }
  product_of.clear();  // the writer's copies of the images are the only ones left
  if (job.link && closing_to_image_) job.link->to_previous = ToArray9(*closing_to_image_);
  closing_to_image_.reset();

  long long busy = cpu.Lap();
  cv::Matx33d closing_to_patch = cv::Matx33d::eye();
  const PatchAdjustment adjusted = PlaceFrames(job, loop_links, between, &closing_to_patch);
  const long long adjusting = cpu.Lap();
  adjust_ns_ += adjusting;
  busy += adjusting;

  // The image covers the keyframes' union; frame_to_patch moves to its pixel grid.
  std::vector<cv::Matx33d> placements;
  cv::Rect2d bounds;
  for (const auto& f : job.frames) {
    if (!f.is_keyframe() || !blended.count(f.index)) continue;
    placements.push_back(ToMatx(f.frame_to_patch));
    const cv::Rect2d b = PatchCanvas::FrameBounds(placements.back(), job.frame_size);
    bounds = bounds.area() > 0 ? (bounds | b) : b;
  }
  const cv::Rect rect(static_cast<int>(std::floor(bounds.x)), static_cast<int>(std::floor(bounds.y)),
                      static_cast<int>(std::ceil(bounds.x + bounds.width)) - static_cast<int>(std::floor(bounds.x)),
                      static_cast<int>(std::ceil(bounds.y + bounds.height)) - static_cast<int>(std::floor(bounds.y)));
  const cv::Matx33d T(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1);
  if (job.closing) closing_to_image_ = T * closing_to_patch;
  const TiffWriteStats written = BlendAndWrite(job, images, placements, rect, store_.PatchImagePath(job.id), options_);
  encode_ns_ += static_cast<long long>(1e9 * written.encode_cpu_seconds);

  // Frames registered late (second chance) go back to input order.
  std::stable_sort(job.frames.begin(), job.frames.end(),
                   [](const FrameRecord& a, const FrameRecord& b) { return a.index < b.index; });
  PatchSidecar sidecar =
      AssemblePatchSidecar(job.id, rect, std::move(job.frames), std::move(job.rejected), job.link, job.pixel_budget,
                           job.frame_size);
  sidecar.frame_camera_matrix = ToArray9(job.camera);
  sidecar.closed_by = job.closed_by;
  if (adjusted.used) {
    sidecar.extra["adjustment"] = {{"rms_px", adjusted.stats.final_rms_px},
                                   {"online_rms_px", adjusted.stats.initial_rms_px},
                                   {"links", static_cast<int>(job.links.size() + loop_links.size())},
                                   {"links_dropped", adjusted.stats.links_dropped},
                                   {"ties", adjusted.ties},
                                   {"focal_px", adjusted.focal},
                                   {"focal_estimated", job.adjust.solver.refine_focal},
                                   {"robust_loss_px", job.adjust.robust_loss_px}};
  } else if (job.adjust.enabled) {
    sidecar.extra["adjustment"] = {{"skipped", adjusted.note}};
  }
  if (adjusted.used) {
    ++adjusted_;
  } else if (job.adjust.enabled) {
    std::lock_guard<std::mutex> lock(unadjusted_mutex_);
    unadjusted_.push_back({job.id, adjusted.miss, adjusted.note});
  }
  // For the global map: the links (thinned) and each keyframe's strongest features.
  std::map<int, int> patch_of;
  for (const auto& f : sidecar.frames) patch_of[f.index] = job.id;
  if (job.closing) patch_of[job.closing->index] = job.next_id;
  std::vector<StoredLink> links;
  std::vector<FrameLink> all = job.links;
  all.insert(all.end(), loop_links.begin(), loop_links.end());
  if (job.closing) all.insert(all.end(), job.closing->links.begin(), job.closing->links.end());
  for (const auto& l : all) {
    auto a = patch_of.find(l.a), b = patch_of.find(l.b);
    if (a == patch_of.end() || b == patch_of.end()) continue;
    const FrameLink thin = Thin(l, kMaxStoredLinkPairs, job.frame_size);
    links.push_back({{a->second, l.a}, {b->second, l.b}, thin.in_a, thin.in_b});
  }
  std::vector<StoredFeatures> stored;
  for (size_t i = 0; i < features.size() && i < key_indices.size(); ++i)
    if (features[i]) stored.push_back(ToStored(key_indices[i], *features[i], job.frame_size));
  // Links and features first: a committed sidecar names only files that are there.
  const std::string stem = store_.PatchSidecarPath(job.id).substr(0, store_.PatchSidecarPath(job.id).size() - 5);
  const std::string rel = std::filesystem::path(stem).parent_path().filename().string() + "/" +
                          std::filesystem::path(stem).filename().string();
  if (!links.empty()) {
    WriteFrameLinks(stem + ".links.json", links);
    sidecar.frame_links = rel + ".links.json";
  }
  if (!stored.empty()) {
    WriteFrameFeatures(stem + ".features", stored);
    sidecar.frame_features = rel + ".features";
  }
  busy_ns_ += busy + cpu.Lap();
  store_.CommitPatch(sidecar);
  ++written_;
  if (on_patch_) on_patch_(sidecar);
}

}  // namespace rolamos
