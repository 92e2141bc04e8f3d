#include "rolamos/mosaicker.hpp"

#include <algorithm>
#include <filesystem>
#include <chrono>
#include <deque>
#include <map>
#include <atomic>
#include <mutex>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "engine/ecc_refine.h"
#include "engine/egomotion.h"
#include "engine/feather.h"
#include "engine/features.h"
#include "engine/motion_gate.h"
#include "engine/patch_canvas.h"
#include "engine/patch_writer.h"
#include "engine/prepared_frame.h"
#include "engine/preprocess.h"
#include "engine/patch_adjustment.h"
#include "engine/registration.h"
#include "engine/colour.h"
#include "engine/static_mask.h"
#include "util/files.h"
#include "engine/stage_options.h"
#include "rolamos/error.hpp"
#include "util/homography.h"
#include "util/memory.h"

namespace rolamos {


namespace {

// The working canvas (refinement and recovery against the patch) at half resolution: a quarter
// of the blending work; the patch image is blended at full resolution when it closes.
constexpr double kWorkingScale = 0.5;

// What the store keeps for the global map: pairs a link, features a frame.
constexpr int kStoredPairsPerLink = 48;
constexpr int kStoredFeatures = 400;

// A frame's features as the store keeps them: at most kStoredFeatures, spread over a grid of the
// frame (each cell's in turn), SIFT descriptors as bytes (OpenCV's are whole numbers below 256).
StoredFeatures ToStored(int index, const Features& f, cv::Size frame) {
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
  for (size_t round = 0; static_cast<int>(keep.size()) < kStoredFeatures; ++round) {
    bool any = false;
    for (const auto& c : cells) {
      if (round >= c.size() || static_cast<int>(keep.size()) >= kStoredFeatures) continue;
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

// Largest distance between where two homographies put the frame's corners.
double MaxCornerShift(const cv::Matx33d& a, const cv::Matx33d& b, cv::Size s) {
  double worst = 0;
  for (const cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(s.width - 1.0, 0),
                              cv::Point2d(0, s.height - 1.0), cv::Point2d(s.width - 1.0, s.height - 1.0)}) {
    const cv::Vec3d u = a * cv::Vec3d(p.x, p.y, 1), v = b * cv::Vec3d(p.x, p.y, 1);
    worst = std::max(worst, std::hypot(u[0] / u[2] - v[0] / v[2], u[1] / u[2] - v[1] / v[2]));
  }
  return worst;
}


}  // namespace

bool MosaickerOptions::IsValid(std::string* error) const {
  if (!ToFeatureOptions(*this).IsValid(error) || !ToEgomotionOptions(*this).IsValid(error) ||
      !ToPreprocessOptions(*this).IsValid(error) || !ToEccOptions(*this).IsValid(error))
    return false;
  if (!(feather_sigma >= 0 && feather_sigma <= 10)) {
    *error = "feather sigma must be in [0, 10] (0 = plain averaging)";
    return false;
  }
  if (!(patch_megapixels >= 0.1 && patch_megapixels <= 2000)) {
    *error = "patch budget " + std::to_string(patch_megapixels) + " megapixels is outside 0.1..2000";
    return false;
  }
  if (mask != "" && mask != "auto" && !std::filesystem::exists(mask)) {
    *error = "static overlay mask \"" + mask + "\" does not exist";
    return false;
  }
  if (!(patch_frames_mb >= 16)) {
    *error = "the memory for a patch's frames must be at least 16 MB, not " + std::to_string(patch_frames_mb);
    return false;
  }
  if (patch_memory_mb < 0) {
    *error = "patch memory budget cannot be negative";
    return false;
  }
  if (checkpoint_frames < 0 || checkpoint_frames == 1) {
    *error = "checkpoint every " + std::to_string(checkpoint_frames) + " frames: 0 (none) or at least 2";
    return false;
  }
  if (max_lost_frames < 1) {
    *error = "max lost frames must be at least 1";
    return false;
  }
  PixelLayout rgba;
  rgba.width = rgba.height = 1024;
  rgba.channels = 4;
  return tiff.IsValid(rgba, error);
}

long long MosaickerOptions::PixelBudget() const {
  long long budget = static_cast<long long>(patch_megapixels * 1e6);
  if (patch_memory_mb > 0)  // the canvas holds 16 bytes a pixel (3 float sums and a weight)
    budget = std::min(budget, static_cast<long long>(patch_memory_mb * 1024 * 1024 / 16));
  return budget;
}

struct Mosaicker::Impl {
  MosaickerOptions options;
  Store store;
  Preprocessor pre;
  FeatureExtractor extractor;
  EgomotionOptions ego_options;
  EccOptions ecc_options;
  SupportOptions support_options;
  PatchFitOptions fit_options;
  PatchWriter writer;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();

  // The first frame fixes the size and the camera.
  cv::Size frame_size;
  cv::Matx33d K = cv::Matx33d::eye();
  std::shared_ptr<const FeatherCode> weights;
  // Static overlays: 255 where the frame is usable (full size), and at the detection scale.
  std::mutex mask_mutex;
  cv::Mat usable, usable_small;
  std::unique_ptr<MotionGate> gate;

  // The patch in progress.
  std::unique_ptr<PatchCanvas> canvas;
  int patch_id = 0;
  int next_patch_id = 1;  // patches are committed later, by the writer thread
  cv::Rect2d data_bounds;
  std::vector<FrameRecord> frames;       // frame_to_patch in first-frame coordinates until closed
  std::vector<RejectedFrame> rejected;
  std::optional<PatchLink> link;         // how this patch joins the one before (first-frame coordinates)
  std::vector<PatchFrame> patch_frames;  // the stitched frames with their features
  // For the adjustment at closing: each stitched frame's image (as blended, aligned with
  // `frames`) and the matches found between the patch's frames.
  std::vector<cv::Mat> images;
  size_t image_bytes = 0;
  std::vector<FrameLink> links;
  PatchAdjustmentOptions adjust_options;
  std::unique_ptr<ColourModel> colour;
  // The last stitched frame: what the next one is registered to.
  PatchFrame prev;
  std::shared_ptr<const Features> last_prepared;      // Push: of the last frame with features
  int lost = 0;
  // Frames rejected while this patch is open, kept for a second chance against later frames.
  struct Pending {
    std::shared_ptr<PreparedFrame> frame;
    FrameReport report;
  };
  std::deque<Pending> pending;
  MosaicSummary summary;
  // Stage timers, in the order of the pipeline.
  enum Stage { kPreprocess, kDetectImage, kFeatures, kMatching, kEgomotion, kRecovery, kPatchFit,
               kEcc, kBlend, kAdjust, kStages };
  // Prepare runs on several threads at once: nanoseconds, added atomically.
  std::atomic<long long> stage_ns[kStages] = {};
  struct Laps {
    Impl* m;
    std::chrono::steady_clock::time_point t = std::chrono::steady_clock::now();
    void operator()(Stage s) {
      const auto now = std::chrono::steady_clock::now();
      m->stage_ns[s] += std::chrono::duration_cast<std::chrono::nanoseconds>(now - t).count();
      t = now;
    }
  };

  Impl(Store s, const MosaickerOptions& o)
      : options(o),
        store(s),
        pre(ToPreprocessOptions(o)),
        extractor(ToFeatureOptions(o)),
        ego_options(ToEgomotionOptions(o)),
        ecc_options(ToEccOptions(o)),
        writer(s, o.tiff) {
    adjust_options.enabled = o.adjust_patches;
    ColourOptions co;
    co.lighting = o.flat_field;
    co.exposure = o.exposure;
    co.water_colour = o.water_colour;
    colour = std::make_unique<ColourModel>(co);
    adjust_options.solver.refine_focal = getenv("ROLAMOS_REFINE_FOCAL") != nullptr;
  }

  // A candidate placement of the frame in the patch, and what supports it.
  struct Candidate {
    EgomotionResult ego;          // from the frame to what it was registered against
    cv::Matx33d to_patch = cv::Matx33d::eye();
    Support support;
    GateVerdict verdict;
    std::string registered_by;    // "" = the previous frame
    int target = -1;              // the frame it was registered against (-1: the patch image)
    bool from_previous() const { return registered_by.empty(); }
    // The link with the frame it was registered against, if any.
    std::vector<FrameLink> Links(int index) const {
      if (target < 0 || !ego.ok) return {};
      return {FrameLink{index, target, ego.inlier_from, ego.inlier_to}};
    }
  };
  // The frame that opens the next patch when the pixel budget closes this one: adjusted with
  // this patch's frames (not blended) to tie the two patches together.
  struct Closing {
    int index = 0;
    cv::Matx33d to_patch;
    std::vector<FrameLink> links;
  };

  void StartPatch(const PreparedFrame& p, const std::optional<PatchLink>& join);
  // Hands the patch to the writer; returns first-frame coordinates -> patch image pixels.
  // Returns the closing frame's pixels -> the patch image's pixels (when `closing` is given).
  cv::Matx33d ClosePatch(const std::string& why, const std::optional<Closing>& closing = std::nullopt);
  void Stitch(const cv::Mat& image, const cv::Matx33d& to_patch,
              const std::shared_ptr<const Features>& f, const FrameReport& report,
              std::vector<FrameLink> found = {});
  FrameReport Reject(FrameReport r, const std::string& reason);
  Candidate Register(const Matches& matches, const cv::Matx33d& target_to_patch, const std::string& by,
                     int target);
  // The frame against the patch's other frames and the patch image, when the previous one failed.
  // `current`: the registration against the previous frame, if any.
  std::vector<Candidate> Recover(const PreparedFrame& p, const Candidate* current, Laps& lap);
  void SecondChance(Laps& lap);
  // The overlay mask at detection scale `s` (empty when there is none).
  cv::Mat ScaledUsable(double s) {
    std::lock_guard<std::mutex> lock(mask_mutex);
    if (usable.empty()) return {};
    cv::Mat small;
    cv::resize(usable, small, cv::Size(), s, s, cv::INTER_NEAREST);
    cv::erode(small, small, cv::Mat(), cv::Point(-1, -1), 4);
    return small;
  }
  FrameMotion MotionFromPrevious(const cv::Matx33d& to_patch) const {
    return MotionOf(prev.to_patch.inv() * to_patch, frame_size);
  }
};

FrameReport Mosaicker::Impl::Reject(FrameReport r, const std::string& reason) {
  r.status = "rejected";
  r.reason = reason;
  r.patch_id = canvas ? patch_id : 0;
  rejected.push_back({r.index, r.source, reason});
  ++summary.rejected;
  return r;
}

void Mosaicker::Impl::StartPatch(const PreparedFrame& p, const std::optional<PatchLink>& join) {
  canvas = std::make_unique<PatchCanvas>(options.PixelBudget(), kWorkingScale);
  patch_id = next_patch_id++;
  data_bounds = cv::Rect2d();
  frames.clear();
  patch_frames.clear();
  images.clear();
  image_bytes = 0;
  links.clear();
  pending.clear();
  link = join;
  gate->Reset();
  prev = PatchFrame{};
  prev.features = p.own;
}

void Mosaicker::Impl::Stitch(const cv::Mat& image, const cv::Matx33d& to_patch,
                             const std::shared_ptr<const Features>& f, const FrameReport& report,
                             std::vector<FrameLink> found) {
  canvas->Add(image, *weights, to_patch);
  if (options.flat_field || options.water_colour) colour->Add(image, usable.size() == image.size() ? usable : cv::Mat());
  images.push_back(image);
  image_bytes += image.total() * image.elemSize();
  if (adjust_options.enabled)
    for (auto& l : found) links.push_back(Thin(std::move(l), adjust_options.max_pairs_per_link, frame_size));
  const cv::Rect2d b = PatchCanvas::FrameBounds(to_patch, frame_size);
  data_bounds = data_bounds.area() > 0 ? (data_bounds | b) : b;
  FrameRecord rec;
  rec.index = report.index;
  rec.source = report.source;
  rec.frame_to_patch = ToArray9(to_patch);
  rec.matches = report.matches;
  rec.inliers = report.inliers;
  rec.ecc = report.ecc;
  rec.status = "stitched";
  frames.push_back(rec);
  PatchFrame pf;
  pf.index = report.index;
  pf.features = f;
  pf.to_patch = to_patch;
  patch_frames.push_back(pf);
  // Features of frames far behind are dropped beyond a bound: memory stays flat on long patches.
  constexpr size_t kKeptFeatures = 400;
  if (patch_frames.size() > kKeptFeatures) patch_frames[patch_frames.size() - kKeptFeatures - 1].features.reset();
  ++summary.stitched;
}

cv::Matx33d Mosaicker::Impl::ClosePatch(const std::string& why, const std::optional<Closing>& closing) {
  pending.clear();
  if (!canvas || frames.empty()) {
    canvas.reset();
    return cv::Matx33d::eye();
  }
  // The frames placed once more, together, as cameras over the seafloor plane; the closing
  // frame (the next patch's first) comes along, unblended, to tie the patches.
  std::vector<int> indices;
  std::vector<cv::Matx33d> online;
  for (const auto& f : frames) {
    indices.push_back(f.index);
    online.push_back(ToMatx(f.frame_to_patch));
  }
  std::vector<FrameLink> all = links;
  if (closing) {
    indices.push_back(closing->index);
    online.push_back(closing->to_patch);
    for (const auto& l : closing->links) all.push_back(Thin(l, adjust_options.max_pairs_per_link, frame_size));
  }
  PatchAdjustment adjusted;
  Laps lap{this};
  if (adjust_options.enabled)
    adjusted = AdjustPatch(indices, online, all, K(0, 0), frame_size, adjust_options);
  lap(kAdjust);
  ++(adjusted.used ? summary.adjusted : summary.unadjusted);
  cv::Rect2d bounds = data_bounds;
  if (adjusted.used) {
    bounds = cv::Rect2d();
    for (size_t i = 0; i < frames.size(); ++i) {
      frames[i].frame_to_patch = ToArray9(adjusted.frame_to_patch[i]);
      const cv::Rect2d b = PatchCanvas::FrameBounds(adjusted.frame_to_patch[i], frame_size);
      bounds = bounds.area() > 0 ? (bounds | b) : b;
    }
    // This patch's coordinates are now the plane's: the link to the previous patch goes through
    // the first frame's adjusted pose.
    if (link) link->to_previous = ToArray9(ToMatx(link->to_previous) * adjusted.frame_to_patch[0].inv());
  }
  // The image covers the frames' union; frame_to_patch moves to the image's pixel grid.
  const cv::Rect rect(static_cast<int>(std::floor(bounds.x)), static_cast<int>(std::floor(bounds.y)),
                      static_cast<int>(std::ceil(bounds.x + bounds.width)) - static_cast<int>(std::floor(bounds.x)),
                      static_cast<int>(std::ceil(bounds.y + bounds.height)) - static_cast<int>(std::floor(bounds.y)));
  const cv::Matx33d T(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1);
  cv::Matx33d closing_to_image = cv::Matx33d::eye();
  if (closing) closing_to_image = T * (adjusted.used ? adjusted.frame_to_patch.back() : closing->to_patch);
  PatchJob job;
  job.images = std::move(images);
  for (size_t i = 0; i < frames.size(); ++i)
    job.placements.push_back(adjusted.used ? adjusted.frame_to_patch[i] : ToMatx(frames[i].frame_to_patch));
  job.weights = weights;
  job.temporal = options.temporal ? &pre : nullptr;
  if (options.flat_field || options.water_colour) job.colour = colour->Correction(frame_size);
  job.exposure = options.exposure;
  // Frames registered late (second chance) go back to input order.
  std::stable_sort(frames.begin(), frames.end(), [](const FrameRecord& a, const FrameRecord& b) { return a.index < b.index; });
  job.sidecar = AssemblePatchSidecar(patch_id, rect, frames, rejected, link, options.PixelBudget(), frame_size);
  job.sidecar.closed_by = why;
  if (adjusted.used) {
    job.sidecar.extra["adjustment"] = {{"rms_px", adjusted.stats.final_rms_px},
                                       {"online_rms_px", adjusted.stats.initial_rms_px},
                                       {"links", static_cast<int>(all.size())},
                                       {"links_dropped", adjusted.stats.links_dropped},
                                       {"focal_px", adjusted.focal}};
  } else if (adjust_options.enabled) {
    job.sidecar.extra["adjustment"] = {{"skipped", adjusted.note}};
  }
  job.data_rect = rect;
  // For the global map: the links (thinned) and each frame's strongest features, spread out.
  std::map<int, int> patch_of;
  for (const auto& f : frames) patch_of[f.index] = patch_id;
  if (closing) patch_of[closing->index] = next_patch_id;
  for (const auto& l : all) {
    auto a = patch_of.find(l.a), b = patch_of.find(l.b);
    if (a == patch_of.end() || b == patch_of.end()) continue;
    const FrameLink thin = Thin(l, kStoredPairsPerLink, frame_size);
    job.links.push_back({{a->second, l.a}, {b->second, l.b}, thin.in_a, thin.in_b});
  }
  for (const auto& pf : patch_frames)
    if (pf.features) job.features.push_back(ToStored(pf.index, *pf.features, frame_size));
  canvas.reset();
  writer.Submit(std::move(job));
  ++summary.patches;
  frames.clear();
  rejected.clear();
  patch_frames.clear();
  images.clear();
  image_bytes = 0;
  links.clear();
  return closing_to_image;
}

Mosaicker::Impl::Candidate Mosaicker::Impl::Register(const Matches& matches, const cv::Matx33d& target_to_patch,
                                                     const std::string& by, int target) {
  Candidate c;
  c.target = target;
  c.ego = EstimateEgomotion(matches.from, matches.to, K, ego_options);
  c.support = AssessSupport(c.ego, frame_size, support_options);
  c.registered_by = by;
  if (c.ego.ok) {
    c.to_patch = target_to_patch * c.ego.H;
    c.verdict = gate->Evaluate(MotionFromPrevious(c.to_patch));
  }
  return c;
}

std::vector<Mosaicker::Impl::Candidate> Mosaicker::Impl::Recover(const PreparedFrame& p, const Candidate* current,
                                                                 Laps& lap) {
  std::vector<Candidate> found;
  const Features& f = *p.own;
  // 0. The previous frame again, in finer detail: a large motion over rugged ground can leave
  //    too few matches at the usual detection scale.
  if ((!current || !current->support.strong) && !images.empty() && patch_frames.back().index == prev.index) {
    FeatureOptions fine = extractor.options();
    fine.detect_scale = std::min(1.0, 1.7 * fine.ScaleFor(frame_size));
    fine.max_features = 2 * fine.max_features;
    const FeatureExtractor detail(fine);
    const double s = fine.detect_scale;
    const Features here = detail.ExtractScaled(pre.DetectionImage(p.spatial, s), s, ScaledUsable(s));
    const Features there = detail.ExtractScaled(pre.DetectionImage(images.back(), s), s, ScaledUsable(s));
    Candidate c = Register(MatchFeatures(here, there, fine), prev.to_patch, "", prev.index);
    if (c.ego.ok) found.push_back(std::move(c));
    if (!found.empty() && found.back().support.strong && found.back().verdict.consistent) {
      lap(kRecovery);
      return found;
    }
  }
  // 1. The patch's recent frames before the previous one that overlap it (the previous frame may
  //    be the bad one: blurred, a fish across it), newest first.
  int tried = 0;
  for (auto it = patch_frames.rbegin(); it != patch_frames.rend() && tried < 4; ++it) {
    if (it->index == prev.index || !it->features) continue;
    if (FootprintOverlap(prev.to_patch, it->to_patch, frame_size) < 0.1) continue;
    ++tried;
    Candidate c = Register(MatchFeatures(f, *it->features, extractor.options()), it->to_patch, "keyframe", it->index);
    if (c.ego.ok) found.push_back(std::move(c));
    if (!found.empty() && found.back().support.strong && found.back().verdict.consistent) break;
  }
  lap(kRecovery);
  for (const auto& c : found) {
    if (c.support.strong && c.verdict.consistent) return found;
    // An unpredicted but strong registration that another frame confirms: a real change of
    // course, no need to look further.
    if (current && current->support.strong && c.support.strong &&
        MaxCornerShift(c.to_patch, current->to_patch, frame_size) < 8.0)
      return found;
  }
  // 2. The patch image around the last frame, a frame's size each way: the frame may have turned
  //    any way (features are rotation invariant) and need not overlap the previous frame.
  const cv::Rect2d around = PatchCanvas::FrameBounds(prev.to_patch, frame_size);
  const double grow = std::max(frame_size.width, frame_size.height);
  const cv::Rect wanted(static_cast<int>(std::floor(around.x - grow)), static_cast<int>(std::floor(around.y - grow)),
                        static_cast<int>(std::ceil(around.width + 2 * grow)), static_cast<int>(std::ceil(around.height + 2 * grow)));
  const double scale = extractor.options().ScaleFor(frame_size);
  cv::Mat gray, mask;
  cv::Point2d origin;
  if (canvas->RenderGray(wanted, scale, &gray, &mask, &origin) && gray.cols >= 16 && gray.rows >= 16) {
    FeatureOptions more = extractor.options();
    more.max_features = 3 * more.max_features;  // the view is several frames large
    const FeatureExtractor wide(more);
    cv::Mat eroded;
    cv::erode(mask, eroded, cv::Mat(), cv::Point(-1, -1), 2);
    const Features mosaic = wide.ExtractScaled(pre.DetectionImage(gray, 1.0), scale, eroded);
    const cv::Matx33d crop_to_patch(1, 0, origin.x, 0, 1, origin.y, 0, 0, 1);
    Candidate c = Register(MatchFeatures(f, mosaic, extractor.options()), crop_to_patch, "patch_mosaic", -1);
    if (c.ego.ok) found.push_back(std::move(c));
  }
  lap(kRecovery);
  return found;
}

// Frames rejected earlier in this patch, tried again against the frame just stitched: a frame
// that failed against its predecessor (blur, a passing fish) often matches its successor.
void Mosaicker::Impl::SecondChance(Laps& lap) {
  for (auto it = pending.begin(); it != pending.end();) {
    const PreparedFrame& p = *it->frame;
    Candidate c = Register(MatchFeatures(*p.own, *prev.features, extractor.options()), prev.to_patch, "second_chance",
                           prev.index);
    if (!c.support.strong) {
      ++it;
      continue;
    }
    cv::Matx33d to_patch = c.to_patch;
    PatchFit fit = FitToPatch(it->report.index, *p.own, frame_size, to_patch, prev, c.ego.inlier_from,
                              c.ego.inlier_to, patch_frames, fit_options);
    if (fit.ok) to_patch = fit.to_patch;
    if (!canvas->Fits(PatchCanvas::FrameBounds(to_patch, frame_size))) {
      ++it;
      continue;
    }
    FrameReport r = it->report;
    r.status = "stitched";
    r.reason.clear();
    r.matches = c.ego.matches;
    r.inliers = c.ego.inliers;
    Stitch(p.spatial, to_patch, p.own, r, fit.ok ? fit.links : c.Links(r.index));  // the chain goes on from the newest
    frames.back().registered_by = "second_chance";
    frames.back().patch_frames = fit.ok ? fit.frames : 1;
    rejected.erase(std::remove_if(rejected.begin(), rejected.end(),
                                  [&](const RejectedFrame& x) { return x.index == r.index; }),
                   rejected.end());
    --summary.rejected;
    ++summary.recovered;
    it = pending.erase(it);
  }
  lap(kRecovery);
}

Mosaicker::Mosaicker(Store store, const MosaickerOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("mosaic options", error);

  // "auto" needs the first frames before the first is prepared: MosaicInput finds the mask and
  // gives the engine its file. Pushed frames have nobody to look ahead: no mask, and said so.
  MosaickerOptions o = options;
  std::string mask_note;
  if (o.mask == "auto") {
    o.mask.clear();
    mask_note = "mask auto: frames pushed one by one are not looked ahead at; no overlay mask (MosaicInput finds one)";
  }
  impl_ = std::make_unique<Impl>(store, o);
  impl_->summary.mask_note = mask_note;
  impl_->next_patch_id = store.NextPatchId();
}

Mosaicker::~Mosaicker() = default;

void Mosaicker::OnPatch(std::function<void(const PatchSidecar&)> callback) {
  impl_->writer.OnPatch(std::move(callback));
}

std::shared_ptr<PreparedFrame> Mosaicker::Prepare(const cv::Mat& input, const std::string& source,
                                                  const std::string& error) {
  Impl& m = *impl_;
  auto p = std::make_shared<PreparedFrame>();
  p->source = source;
  p->error = input.empty() ? (error.empty() ? "unreadable" : error) : "";
  if (input.empty()) return p;
  Impl::Laps lap{&m};
  cv::Mat frame = input;
  if (frame.depth() != CV_8U) frame.convertTo(frame, CV_8U, 1.0 / 257.0);
  if (frame.channels() == 1) cv::cvtColor(frame, frame, cv::COLOR_GRAY2BGR);
  if (frame.channels() == 4) cv::cvtColor(frame, frame, cv::COLOR_BGRA2BGR);
  p->size = frame.size();
  // A frame of another size than the survey's is rejected by Integrate, which knows the survey.
  p->spatial = m.pre.Spatial(frame);
  lap(Impl::kPreprocess);
  const double scale = m.extractor.options().ScaleFor(p->size);
  cv::Mat usable_small;
  p->detect = m.pre.DetectionImage(p->spatial, scale, &usable_small);
  if (!m.options.mask.empty()) {
    std::lock_guard<std::mutex> lock(m.mask_mutex);
    if (m.usable.empty() || m.usable.size() != p->size) {
      m.usable = 255 - ReadStaticMask(m.options.mask, p->size);
      cv::resize(m.usable, m.usable_small, p->detect.size(), 0, 0, cv::INTER_NEAREST);
      // Features need a margin around an overlay: their descriptors reach out.
      cv::erode(m.usable_small, m.usable_small, cv::Mat(), cv::Point(-1, -1), 4);
    }
    usable_small = usable_small.empty() ? m.usable_small : (usable_small & m.usable_small);
  }
  lap(Impl::kDetectImage);
  p->own = std::make_shared<const Features>(m.extractor.ExtractScaled(p->detect, scale, usable_small));
  lap(Impl::kFeatures);
  return p;
}

void Mosaicker::MatchAhead(PreparedFrame* frame, const std::shared_ptr<const Features>& previous) {
  if (!frame->own || frame->own->empty() || !previous || previous->empty()) return;
  Impl::Laps lap{impl_.get()};
  frame->matches = MatchFeatures(*frame->own, *previous, impl_->extractor.options());
  frame->matched_to = previous;
  lap(Impl::kMatching);
}

FrameReport Mosaicker::Push(const cv::Mat& frame, const std::string& source, const std::string& error) {
  auto prepared = Prepare(frame, source, error);
  MatchAhead(prepared.get(), impl_->last_prepared);
  if (prepared->own && !prepared->own->empty()) impl_->last_prepared = prepared->own;
  return Integrate(prepared);
}

FrameReport Mosaicker::Integrate(const std::shared_ptr<PreparedFrame>& prepared) {
  Impl& m = *impl_;
  const PreparedFrame& p = *prepared;
  const auto t0 = std::chrono::steady_clock::now();
  Impl::Laps lap{&m};
  FrameReport r;
  r.index = m.summary.frames++;
  r.source = p.source;
  auto done = [&](FrameReport rep) {
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  };
  if (!p.error.empty()) return done(m.Reject(r, p.error));
  if (m.frame_size.area() == 0) {
    m.frame_size = p.size;
    m.K = m.pre.CameraMatrix(p.size);
    cv::Mat w = FeatherWeights(p.size, m.options.feather_sigma);
    if (!m.usable.empty() && m.usable.size() == p.size) w.setTo(0, m.usable == 0);  // overlays never blend
    m.weights = std::make_shared<const FeatherCode>(w);
    MotionGateOptions g;
    g.enabled = m.options.kalman;
    m.gate = std::make_unique<MotionGate>(g, p.size);
  }
  if (p.size != m.frame_size)
    return done(m.Reject(r, "size_changed: " + std::to_string(p.size.width) + "x" +
                                std::to_string(p.size.height) + ", the survey is " +
                                std::to_string(m.frame_size.width) + "x" +
                                std::to_string(m.frame_size.height)));
  const cv::Mat& spatial = p.spatial;
  const auto& features = p.own;
  // A frame that cannot be registered: kept for a second chance against the frames after it;
  // the patch closes only after several in a row failed against every frame of it and its image.
  auto lost_one = [&](const std::string& reason) {
    FrameReport rep = m.Reject(r, reason);
    if (m.gate) m.gate->Skip();
    if (m.canvas && m.options.recover && features && !features->empty()) {
      m.pending.push_back({prepared, rep});
      if (m.pending.size() > 6) m.pending.pop_front();
    }
    if (++m.lost >= m.options.max_lost_frames && m.canvas) {
      m.ClosePatch("lost_tracking");  // the next good frame starts a new patch
      m.lost = 0;
    }
    return done(rep);
  };
  if (features->strong < m.options.min_inliers) return lost_one("featureless");
  if (!m.canvas) {
    m.StartPatch(p, std::nullopt);
    r.started_patch = true;
    m.Stitch(spatial, cv::Matx33d::eye(), features, r);
    m.prev = m.patch_frames.back();
    r.status = "stitched";
    r.patch_id = m.patch_id;
    m.lost = 0;
    return done(r);
  }
  m.gate->Predict(r.index - m.prev.index);
  // 1. Against the previous frame (usually matched by Prepare already).
  Matches matches = p.matched_to == m.prev.features
                        ? p.matches
                        : MatchFeatures(*features, *m.prev.features, m.extractor.options());
  lap(Impl::kMatching);
  Impl::Candidate best = m.Register(matches, m.prev.to_patch, "", m.prev.index);
  lap(Impl::kEgomotion);
  r.matches = best.ego.matches;
  r.inliers = best.ego.inliers;
  r.bilateral_error = best.ego.bilateral_error_mean;
  // The same view again (a repeated frame, a vehicle holding still): nothing to add.
  if (best.ego.ok && best.support.strong &&
      MaxCornerShift(best.ego.H, cv::Matx33d::eye(), m.frame_size) < 0.25) {
    m.gate->Skip();
    return done(m.Reject(r, "duplicate of frame " + std::to_string(m.prev.index)));
  }
  // 2. The motion model arbitrates: a strong registration stands even when unpredicted (a real
  //    change of course); a weak one stands only when predicted. Otherwise the frame is tried
  //    against the patch's other frames and its image, and the best candidate is chosen: strong
  //    ones first, closest to the prediction among them.
  // A weak registration (few or clustered inliers) stands when the motion model predicted it, or,
  // while the model is still learning, when it is a plausible motion from the previous frame
  // (a patch's first frames: nothing else to go by). Either way it is flagged doubtful.
  auto usable = [&](const Impl::Candidate& c) {
    if (!c.ego.ok) return false;
    if (c.support.strong) return true;
    if (!c.support.conditioned || !m.options.kalman) return false;
    return c.verdict.informed ? c.verdict.consistent : c.from_previous();
  };
  bool accept = usable(best);
  // Strong and predicted beats strong alone (a course change, or a texture that repeats turned
  // about), which beats weak but predicted.
  auto rank = [](const Impl::Candidate& c) {
    return c.support.strong ? (c.verdict.consistent ? 3 : 2) : 1;
  };
  if (!accept || !best.support.strong || !best.verdict.consistent) {
    if (m.options.recover) {
      std::vector<Impl::Candidate> more = m.Recover(p, best.ego.ok ? &best : nullptr, lap);
      if (best.ego.ok) more.push_back(best);
      const Impl::Candidate* pick = nullptr;
      for (const auto& c : more) {
        if (!usable(c)) continue;
        if (!pick || rank(c) > rank(*pick) ||
            (rank(c) == rank(*pick) && c.verdict.distance2 < pick->verdict.distance2))
          pick = &c;
      }
      if (pick) {
        best = *pick;
        accept = true;
      }
    }
  }
  if (!accept) {
    std::string reason = best.ego.ok ? (best.verdict.consistent ? best.support.weakness : "kalman_gate")
                                     : best.ego.failure;
    return lost_one(reason);
  }
  const bool doubtful = !best.support.strong;
  if (!best.from_previous()) {
    r.matches = best.ego.matches;
    r.inliers = best.ego.inliers;
    r.bilateral_error = best.ego.bilateral_error_mean;
  }
  cv::Matx33d to_patch = best.to_patch;
  // 3. The placement fitted against every patch frame under it, so that errors do not add up
  //    from pair to pair.
  int fitted = 1;
  std::vector<FrameLink> fitted_links;
  if (m.options.patch_fit) {
    const PatchFrame& anchor = m.prev;
    std::vector<cv::Point2f> from, to;
    if (best.from_previous()) {
      from = best.ego.inlier_from;
      to = best.ego.inlier_to;
    }
    PatchFit fit = FitToPatch(r.index, *features, m.frame_size, to_patch, anchor, from, to, m.patch_frames,
                              m.fit_options);
    if (!best.from_previous() && fit.ok) fit.frames = std::max(fit.frames, 1);
    // The fit must leave the frame a motion a camera can make from the previous one.
    if (fit.ok && !IsPlausibleMotion(m.prev.to_patch.inv() * fit.to_patch, m.frame_size, m.support_options))
      fit.ok = false;
    if (fit.ok) {
      to_patch = fit.to_patch;
      fitted = fit.frames;
      fitted_links = std::move(fit.links);
    }
  }
  if (fitted_links.empty()) fitted_links = best.Links(r.index);
  // Loop closures within the patch (an earlier lane under this frame), for the adjustment.
  if (m.adjust_options.enabled)
    for (auto& l : LinkOlderFrames(r.index, *features, m.frame_size, to_patch, m.patch_frames, m.fit_options))
      fitted_links.push_back(std::move(l));
  lap(Impl::kPatchFit);
  const FrameMotion motion = m.MotionFromPrevious(to_patch);
  const size_t frame_bytes = spatial.total() * spatial.elemSize();
  const bool memory_full =
      m.image_bytes + frame_bytes > static_cast<size_t>(m.options.patch_frames_mb * 1024 * 1024);
  const bool checkpoint = m.options.checkpoint_frames > 0 &&
                          static_cast<int>(m.frames.size()) >= m.options.checkpoint_frames;
  if (memory_full || checkpoint || !m.canvas->Fits(PatchCanvas::FrameBounds(to_patch, m.frame_size))) {
    // The pixel budget is reached: close the patch, start the next one with this frame, and
    // remember how the two join (consecutive patches are linked by this frame's homography).
    const int old_id = m.patch_id;
    Impl::Closing closing;
    closing.index = r.index;
    closing.to_patch = to_patch;
    closing.links = fitted_links;
    PatchLink join;
    join.previous_patch = old_id;
    join.to_previous = ToArray9(m.ClosePatch(memory_full ? "frame_memory" : checkpoint ? "checkpoint" : "pixel_budget", closing));
    m.StartPatch(p, join);
    r.started_patch = true;
    m.Stitch(spatial, cv::Matx33d::eye(), features, r);
    m.prev = m.patch_frames.back();
    m.lost = 0;
    r.status = "stitched";
    r.patch_id = m.patch_id;
    return done(r);
  }
  if (m.options.ecc) {
    cv::Mat gray;
    cv::cvtColor(spatial, gray, cv::COLOR_BGR2GRAY);
    EccResult ecc = RefineWithEcc(gray, to_patch, *m.canvas, m.ecc_options,
                                  m.usable.size() == m.frame_size ? m.usable : cv::Mat());
    r.ecc = ecc.correlation;
    if (ecc.applied) {
      r.ecc_shift = MaxCornerShift(to_patch, ecc.frame_to_patch, m.frame_size);
      to_patch = ecc.frame_to_patch;
    }
  }
  lap(Impl::kEcc);
  m.gate->Accept(motion);
  m.Stitch(spatial, to_patch, features, r, std::move(fitted_links));
  m.prev = m.patch_frames.back();
  m.lost = 0;
  lap(Impl::kBlend);
  FrameRecord& rec = m.frames.back();
  if (best.ego.motion && best.from_previous()) {
    Egomotion e;
    for (int i = 0; i < 9; ++i) e.R[static_cast<size_t>(i)] = best.ego.motion->R.val[i];
    for (int i = 0; i < 3; ++i) {
      e.t[static_cast<size_t>(i)] = best.ego.motion->t[i];
      e.n[static_cast<size_t>(i)] = best.ego.motion->n[i];
    }
    rec.egomotion = e;
  }
  rec.bilateral_error = best.ego.bilateral_error_mean;
  rec.ecc_shift_px = r.ecc_shift;
  if (!best.from_previous()) rec.registered_by = best.registered_by;
  if (doubtful) rec.doubtful = true;
  if (m.options.patch_fit) rec.patch_frames = fitted;
  if (m.options.recover && !m.pending.empty()) m.SecondChance(lap);
  r.status = "stitched";
  r.patch_id = m.patch_id;
  return done(r);
}

MosaicSummary Mosaicker::Finish() {
  Impl& m = *impl_;
  m.ClosePatch("end");
  m.writer.Wait();
  if ((m.options.flat_field || m.options.water_colour) && m.colour->frames() > 0)
    WriteFileAtomic(m.store.dir() + "/lighting.json", m.colour->ToJson());
  m.summary.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - m.start).count();
  m.summary.peak_rss_mb = PeakRssMb();
  static const char* names[] = {"preprocess", "detection image", "features", "matching", "egomotion",
                                "recovery", "patch fit", "ecc", "working canvas", "adjustment"};
  m.summary.stage_seconds.clear();
  for (int i = 0; i < Impl::kStages; ++i)
    m.summary.stage_seconds.emplace_back(names[i], 1e-9 * static_cast<double>(m.stage_ns[i].load()));
  // The writer's thread: the temporal filter, full-resolution blending and encoding of patches.
  m.summary.stage_seconds.emplace_back("patch writing", m.writer.busy_seconds());
  return m.summary;
}

}  // namespace rolamos
