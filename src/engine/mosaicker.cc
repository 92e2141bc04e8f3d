#include "rolamos/mosaicker.hpp"

#include <chrono>
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
#include "engine/stage_options.h"
#include "rolamos/error.hpp"
#include "util/homography.h"
#include "util/memory.h"

namespace rolamos {


namespace {

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
  if (patch_memory_mb < 0) {
    *error = "patch memory budget cannot be negative";
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
  PatchWriter writer;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();

  // The first frame fixes the size and the camera.
  cv::Size frame_size;
  cv::Matx33d K = cv::Matx33d::eye();
  std::unique_ptr<FeatherCode> weights;
  std::unique_ptr<MotionGate> gate;

  // The patch in progress.
  std::unique_ptr<PatchCanvas> canvas;
  int patch_id = 0;
  int next_patch_id = 1;  // patches are committed later, by the writer thread
  cv::Rect2d data_bounds;
  std::vector<FrameRecord> frames;       // frame_to_patch in first-frame coordinates until closed
  std::vector<RejectedFrame> rejected;
  std::optional<PatchLink> link;         // how this patch joins the one before (first-frame coordinates)
  // The last stitched frame: what the next one is registered to.
  std::shared_ptr<const Features> prev_features;      // of the last stitched frame
  std::shared_ptr<const Features> last_prepared;      // Push: of the last frame with features
  cv::Matx33d prev_to_patch = cv::Matx33d::eye();
  cv::Mat prev_filtered;
  int lost = 0;
  MosaicSummary summary;
  // Stage timers, in the order of the pipeline.
  enum Stage { kPreprocess, kDetectImage, kFeatures, kMatching, kEgomotion, kTemporal, kEcc, kBlend, kStages };
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
        writer(s, o.tiff) {}

  void StartPatch(const cv::Mat& filtered, const std::shared_ptr<const Features>& f,
                  const std::optional<PatchLink>& join);
  // Hands the patch to the writer; returns first-frame coordinates -> patch image pixels.
  cv::Matx33d ClosePatch();
  void Stitch(const cv::Mat& filtered, const cv::Matx33d& to_patch,
              const std::shared_ptr<const Features>& f, const FrameReport& report);
  FrameReport Reject(FrameReport r, const std::string& reason);
};

FrameReport Mosaicker::Impl::Reject(FrameReport r, const std::string& reason) {
  r.status = "rejected";
  r.reason = reason;
  r.patch_id = canvas ? patch_id : 0;
  rejected.push_back({r.index, r.source, reason});
  ++summary.rejected;
  return r;
}

void Mosaicker::Impl::StartPatch(const cv::Mat& filtered, const std::shared_ptr<const Features>& f,
                                 const std::optional<PatchLink>& join) {
  canvas = std::make_unique<PatchCanvas>(options.PixelBudget());
  patch_id = next_patch_id++;
  data_bounds = cv::Rect2d();
  frames.clear();
  link = join;
  gate->Reset();
  prev_features = f;
  prev_to_patch = cv::Matx33d::eye();
  prev_filtered = filtered;
}

void Mosaicker::Impl::Stitch(const cv::Mat& filtered, const cv::Matx33d& to_patch,
                             const std::shared_ptr<const Features>& f, const FrameReport& report) {
  canvas->Add(filtered, *weights, to_patch);
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
  prev_features = f;
  prev_to_patch = to_patch;
  prev_filtered = filtered;
  lost = 0;
  ++summary.stitched;
}

cv::Matx33d Mosaicker::Impl::ClosePatch() {
  if (!canvas || frames.empty()) {
    canvas.reset();
    return cv::Matx33d::eye();
  }
  // The image covers the frames' union; frame_to_patch moves to the image's pixel grid.
  const cv::Rect rect(static_cast<int>(std::floor(data_bounds.x)),
                      static_cast<int>(std::floor(data_bounds.y)),
                      static_cast<int>(std::ceil(data_bounds.x + data_bounds.width)) -
                          static_cast<int>(std::floor(data_bounds.x)),
                      static_cast<int>(std::ceil(data_bounds.y + data_bounds.height)) -
                          static_cast<int>(std::floor(data_bounds.y)));
  const cv::Matx33d T(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1);
  PatchJob job;
  job.sidecar = AssemblePatchSidecar(patch_id, rect, frames, rejected, link, canvas->pixel_budget(), frame_size);
  job.canvas = std::move(canvas);
  job.data_rect = rect;
  writer.Submit(std::move(job));
  ++summary.patches;
  frames.clear();
  rejected.clear();
  return T;
}

Mosaicker::Mosaicker(Store store, const MosaickerOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("mosaic options", error);
  impl_ = std::make_unique<Impl>(store, options);
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
  p->detect = m.pre.DetectionImage(p->spatial);
  lap(Impl::kDetectImage);
  p->own = std::make_shared<const Features>(m.extractor.Extract(p->detect));
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
    m.weights = std::make_unique<FeatherCode>(FeatherWeights(p.size, m.options.feather_sigma));
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
  auto lost_one = [&](const std::string& reason) {
    FrameReport rep = m.Reject(r, reason);
    if (++m.lost >= m.options.max_lost_frames && m.canvas) {
      m.ClosePatch();  // tracking lost: the next good frame starts a new patch
      m.lost = 0;
    }
    return done(rep);
  };
  if (static_cast<int>(features->points.size()) < m.options.min_inliers)
    return lost_one("featureless");
  if (!m.canvas) {
    m.StartPatch(spatial, features, std::nullopt);
    r.started_patch = true;
    m.Stitch(spatial, cv::Matx33d::eye(), features, r);
    r.status = "stitched";
    r.patch_id = m.patch_id;
    return done(r);
  }
  // Usually Prepare matched against the right frame already; after a rejected frame, match again.
  Matches matches = p.matched_to == m.prev_features
                        ? p.matches
                        : MatchFeatures(*features, *m.prev_features, m.extractor.options());
  lap(Impl::kMatching);
  EgomotionResult ego = EstimateEgomotion(matches.from, matches.to, m.K, m.ego_options);
  lap(Impl::kEgomotion);
  r.matches = ego.matches;
  r.inliers = ego.inliers;
  r.bilateral_error = ego.bilateral_error_mean;
  if (!ego.ok) return lost_one(ego.failure);
  const std::string gate =
      m.gate->Check(MotionOf(ego.H, m.frame_size), r.index - m.frames.back().index);
  if (!gate.empty()) return lost_one(gate);

  cv::Matx33d to_patch = m.prev_to_patch * ego.H;
  if (!m.canvas->Fits(PatchCanvas::FrameBounds(to_patch, m.frame_size))) {
    // The pixel budget is reached: close the patch, start the next one with this frame, and
    // remember how the two join (consecutive patches are linked by this frame's homography).
    const int old_id = m.patch_id;
    const cv::Matx33d T = m.ClosePatch();
    PatchLink join;
    join.previous_patch = old_id;
    join.to_previous = ToArray9(T * to_patch);
    m.StartPatch(spatial, features, join);
    r.started_patch = true;
    m.Stitch(spatial, cv::Matx33d::eye(), features, r);
    r.status = "stitched";
    r.patch_id = m.patch_id;
    return done(r);
  }
  cv::Mat filtered = m.pre.Temporal(spatial, m.prev_filtered, ego.H);
  lap(Impl::kTemporal);
  if (m.options.ecc) {
    cv::Mat gray;
    cv::cvtColor(filtered, gray, cv::COLOR_BGR2GRAY);
    EccResult ecc = RefineWithEcc(gray, to_patch, *m.canvas, m.ecc_options);
    r.ecc = ecc.correlation;
    if (ecc.applied) {
      r.ecc_shift = MaxCornerShift(to_patch, ecc.frame_to_patch, m.frame_size);
      to_patch = ecc.frame_to_patch;
    }
  }
  lap(Impl::kEcc);
  m.Stitch(filtered, to_patch, features, r);
  lap(Impl::kBlend);
  if (ego.motion) {
    Egomotion e;
    for (int i = 0; i < 9; ++i) e.R[static_cast<size_t>(i)] = ego.motion->R.val[i];
    for (int i = 0; i < 3; ++i) {
      e.t[static_cast<size_t>(i)] = ego.motion->t[i];
      e.n[static_cast<size_t>(i)] = ego.motion->n[i];
    }
    m.frames.back().egomotion = e;
  }
  m.frames.back().bilateral_error = ego.bilateral_error_mean;
  m.frames.back().ecc_shift_px = r.ecc_shift;
  r.status = "stitched";
  r.patch_id = m.patch_id;
  return done(r);
}

MosaicSummary Mosaicker::Finish() {
  Impl& m = *impl_;
  m.ClosePatch();
  m.writer.Wait();
  m.summary.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - m.start).count();
  m.summary.peak_rss_mb = PeakRssMb();
  static const char* names[] = {"preprocess", "detection image", "features", "matching",
                                "egomotion", "temporal", "ecc", "blend"};
  m.summary.stage_seconds.clear();
  for (int i = 0; i < Impl::kStages; ++i)
    m.summary.stage_seconds.emplace_back(names[i], 1e-9 * static_cast<double>(m.stage_ns[i].load()));
  return m.summary;
}

}  // namespace rolamos
