// MosaicInput: a frame source run through the engine on every core. Frames are prepared
// (decoded, filtered, features found and matched to the frame before) by one worker per core,
// several at once, while the calling thread integrates them in order.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <functional>
#include <cstdio>
#include <map>
#include <optional>
#include <mutex>
#include <thread>

#include "input/frame_source.h"
#include "input/live_preview.h"
#include "input/live_source.h"
#include "input/live_status.h"
#include "input/overlay_search.h"
#include "input/load_shedding.h"
#include "engine/prepared_frame.h"
#include "engine/self_calibration.h"
#include "engine/preprocess.h"
#include "engine/static_mask.h"
#include "store/writer_lock.h"
#include "util/cpu_time.h"
#include "util/codecs.h"
#include "util/files.h"

#include <opencv2/imgproc.hpp>
#include "engine/stage_options.h"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"

namespace rolamos {

namespace fs = std::filesystem;

namespace {

// How far the picture moved between two frames (pixels of their size), by phase correlation at
// a quarter size; 0 where it cannot tell (a turn, a frame of other content).
double ShiftBetween(const cv::Mat& a_small, const cv::Mat& b_small, double scale) {
  double response = 0;
  const cv::Point2d d = cv::phaseCorrelate(a_small, b_small, cv::noArray(), &response);
  return response > 0.05 ? std::hypot(d.x, d.y) / scale : 0;
}

// Up to ten readable frames of one size from the start of `input`: k1 estimated from them and
// the calibration written to `path`. Distortion shows where a point is seen at two distances from
// the centre: frames that barely moved (a video at 95 % overlap) say nothing, so from a video the
// frames are taken a quarter of the frame's height of motion apart (within its first 90 frames);
// stills, which move that much from one to the next, are taken as they come.
SelfCalibrationResult CalibrateFromInput(const std::string& input, const std::string& path,
                                         const FeatureOptions& features) {
  auto source = FrameSource::Open(input);
  const bool spaced = source->coded_video();
  std::vector<cv::Mat> gray, consecutive;
  cv::Mat last_small;
  double moved = 0;
  InputFrame f;
  for (int read = 0; gray.size() < 10 && read < 90 && source->Next(&f); ++read) {
    if (f.image.empty()) continue;
    cv::Mat g;
    cv::cvtColor(f.image, g, f.image.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
    if (!gray.empty() && g.size() != gray[0].size()) continue;
    if (consecutive.size() < 10) consecutive.push_back(g);
    if (spaced) {  // stills are taken as they come: their motion is not measured
      const double scale = 0.25;
      cv::Mat small;
      cv::resize(g, small, cv::Size(), scale, scale, cv::INTER_AREA);
      small.convertTo(small, CV_32F);
      if (!last_small.empty()) moved += ShiftBetween(last_small, small, scale);
      last_small = small;
    }
    if (gray.empty() || !spaced || moved >= 0.25 * std::min(g.cols, g.rows)) {
      gray.push_back(g);
      moved = 0;
    }
  }
  if (gray.size() < 4) gray = consecutive;  // a vehicle holding still, or motion it cannot tell
  if (gray.size() < 2)
    Fail(input, "automatic calibration needs two readable frames of one size, found " + std::to_string(gray.size()));
  SelfCalibrationResult r = EstimateRadialDistortion(gray, features);
  WriteCalibration(path, r.calibration);
  return r;
}


// Automatic calibration: radial distortion from the first frames, written into the store so the
// run can be repeated with it. Returns the options to use and a one-line account.
MosaickerOptions AutoCalibrate(const std::string& input, const Store& store,
                               MosaickerOptions options, std::string* note) {
  const std::string path = store.dir() + "/calibration.yml";
  const SelfCalibrationResult r = CalibrateFromInput(input, path, ToFeatureOptions(options));
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "calibration auto: k1 = %.3f (f = 0.9 x width assumed), homography inliers %d -> %d "
                "over %d frame pairs; written to %s",
                r.k1, r.inliers_uncorrected, r.inliers_corrected, r.pairs, path.c_str());
  *note = buf;
  if (!r.why_none.empty()) *note += " (no distortion taken out: " + r.why_none + ")";
  // No distortion found: the frames as they are, the focal length from the field of view as
  // without a file (the file is kept, for the record). Found: the file's focal length is only
  // assumed, where the adjustment starts.
  options.calibration = r.k1 == 0 ? "" : path;
  options.calibration_focal_measured = false;
  return options;
}

// The overlay mask found, written into the store as an image the user can look at, edit and
// give back; the options use it.
MosaickerOptions UseOverlay(const StaticMask& found, const Store& store, MosaickerOptions options,
                            std::string* note) {
  *note = "mask auto: " + found.note;
  options.mask = "";
  if (!found.mask.empty()) {
    const std::string path = store.dir() + "/static_mask.png";
    std::vector<uchar> png;
    if (!EncodeImage(".png", found.mask, &png)) Fail(path, "the overlay's mask could not be encoded as PNG");
    WriteFileAtomic(path, std::string(png.begin(), png.end()));
    options.mask = path;
    char share[64];
    std::snprintf(share, sizeof share, ": %.1f %% of the frame left out", 100 * found.fraction);
    *note += share + std::string("; written to ") + path;
  }
  return options;
}

// A source whose first frames were taken early (the overlay search needs them before the
// mapping starts): those are handed out first, then the source's own, so none is read twice.
// From a live source the held frames keep their arrival times, and count as in flight once
// handed out, as the live source counts its own.
class HeldSource : public FrameSource {
 public:
  using Clock = std::chrono::steady_clock;
  explicit HeldSource(FrameSource* source) : source_(source), live_(dynamic_cast<const LiveSource*>(source)) {}
  // Reads the source's next frame and holds it (with its arrival, live); null at the end.
  const InputFrame* HoldNext() {
    const auto held = HoldMany(1);
    return held.empty() ? nullptr : held.front();
  }
  // Reads up to n frames at once (in parallel where the source can) and holds them; returns them
  // (fewer at the end). A live source's are read one by one, each with its own arrival.
  std::vector<const InputFrame*> HoldMany(int n) {
    std::vector<const InputFrame*> held;
    for (int want = n; want > 0;) {
      if (stop && stop->load()) {  // the overlay search stops reading too
        stopped_ = true;
        break;
      }
      std::vector<InputFrame> taken;
      const int got = source_->Take(live_ ? 1 : want, &taken);
      if (got == 0) break;
      // A live source counts what it hands out as in flight; held frames count once handed on
      // (Next), beyond the backlog bound by design.
      if (live_ && in_flight) *in_flight -= got;
      for (InputFrame& f : taken) {
        first_.push_back({std::move(f), live_ ? live_->arrival() : Clock::time_point{}});
        held.push_back(&first_.back().frame);
      }
      want -= got;
    }
    return held;
  }
  size_t held() const { return first_.size(); }
  bool Next(InputFrame* f) override {
    // The overlay search going on: frames are read `look_ahead` ahead of the mapping, each looked
    // at as it is read, so that a mask found in a window reaches every frame of that window.
    while (look_ahead > 0 && static_cast<int>(first_.size()) <= look_ahead) {
      const InputFrame* held = HoldNext();
      if (!held) {
        look_ahead = 0;  // the input ended (or was stopped): the frames held go on without waiting again
        break;
      }
      look(*held);
    }
    if (!first_.empty()) {
      if (in_flight) ++*in_flight;
      *f = std::move(first_.front().frame);
      arrival_ = first_.front().arrival;
      first_.pop_front();
      return true;
    }
    if (stop && stop->load()) {  // the frames read already are mapped
      stopped_ = true;
      return false;
    }
    if (!source_->Next(f)) return false;
    if (live_) arrival_ = live_->arrival();
    return true;
  }
  int count() const override { return source_->count(); }
  bool coded_video() const override { return source_->coded_video(); }
  // Arrival of the frame Next returned last (live sources only).
  Clock::time_point arrival() const { return arrival_; }
  std::atomic<long>* in_flight = nullptr;  // live: frames taken and not yet mapped
  // Set: no frame is read any more (MosaicInput's stop; a live source has its own).
  const std::atomic<bool>* stop = nullptr;
  // While set (from the thread that calls Next, under the caller's lock): frames read ahead, at
  // most this many, and `look` called on each as it is read.
  int look_ahead = 0;
  std::function<void(const InputFrame&)> look;
  bool stopped() const { return stopped_; }

 private:
  struct Held {
    InputFrame frame;
    Clock::time_point arrival;
  };
  FrameSource* source_;
  const LiveSource* live_;  // the same source when it is live (arrival times), else null
  std::deque<Held> first_;
  Clock::time_point arrival_{};
  std::atomic<bool> stopped_{false};  // read by the engine's thread, set by a preparer's
};

// The same from the first frames of a folder, list or video, which `source` keeps for the
// mosaicking (unreadable ones too: the engine reports them in order).
MosaickerOptions AutoMask(HeldSource* source, const std::string& input, const Store& store,
                          MosaickerOptions options, std::string* note,
                          const std::function<void(const std::string&)>& on_note) {
  const StaticMaskOptions mo;
  std::vector<cv::Mat> frames;
  // As many frames at once as are still wanted (decoded on every core), again past unreadable
  // ones, up to three times as many as wanted.
  for (int read = 0; static_cast<int>(frames.size()) < mo.frames && read < 3 * mo.frames;) {
    const auto held = source->HoldMany(std::min(mo.frames - static_cast<int>(frames.size()), 3 * mo.frames - read));
    if (held.empty()) break;
    for (const InputFrame* f : held)
      if (!f->image.empty()) frames.push_back(f->image);
    read += static_cast<int>(held.size());
  }
  StaticMask found = FindOverlay(frames, options);
  if (found.conclusive) {
    found.note += " in the first " + std::to_string(frames.size()) + " frames";
  } else if (!source->stopped() && static_cast<int>(frames.size()) >= mo.frames) {
    // A descent through open water, a vehicle holding still: the frames after these may tell (a
    // shorter input has none). The input is read again for it; the frames held stay held for the
    // engine.
    OverlaySearchOptions search;
    if (on_note)
      search.progress = [&](int read) {
        on_note("mask auto: the first frames could not tell (a descent?); reading on for the overlay: " +
                std::to_string(read) + " frames read");
      };
    const StaticMask further = SearchOverlayFurther(input, static_cast<int>(source->held()), options, search, source->stop);
    found = further.conclusive ? further : StaticMask{cv::Mat(), 0, found.note + "; " + further.note, false};
  }
  return UseOverlay(found, store, options, note);
}

}  // namespace

namespace {

// Frames from `source` through `mosaicker`: decoded and prepared on every core, integrated in
// order. `on_taken(i)` is called as frame i leaves the source; `on_frame` after it is integrated.
// Returns the seconds spent decoding (all threads).
double RunPipeline(FrameSource* source, Mosaicker& mosaicker,
                   const std::function<void(const FrameReport&, int)>& on_frame,
                   const std::function<void(long)>& on_taken, long max_ahead = 0,
                   const std::function<void()>& on_idle = nullptr, double idle_s = 0) {
  // Frames are decoded and prepared (undistorted, the tracking pyramid) by one worker per core,
  // several at once, while this thread integrates them in order (tracking, registration, gate,
  // ECC, blending); keyframes are filtered and described on the engine's workers, and closed
  // patches written on the writer's, meanwhile.
  const int workers = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  // Frames taken from the source ahead of integration, at most (live: within its backlog bound).
  const long ahead = max_ahead > 0 ? std::min<long>(workers + 1, max_ahead) : workers + 1;
  std::mutex source_mutex, mutex;
  std::condition_variable changed;
  std::map<long, std::shared_ptr<PreparedFrame>> ready;  // prepared, waiting in order
  long taken = 0, integrated = 0, total = -1;             // total known at the end
  // Frames whose integration has ended: a live source counts the frame being integrated in its
  // backlog, so the look-ahead is bounded by these there.
  long finished = 0;
  const bool bounded = max_ahead > 0;
  bool stopping = false;
  std::exception_ptr failure;
  std::atomic<long long> decode_ns{0};
  auto prepare_frames = [&] {
    try {
      for (;;) {
        InputFrame f;
        long index;
        {
          // Frames leave the source in order, numbered as they leave (video decodes in order).
          // The room ahead is checked under the source's lock: two workers that both saw one
          // free slot must not both take a frame (the live backlog would pass its bound).
          std::lock_guard<std::mutex> source_lock(source_mutex);
          {
            std::unique_lock<std::mutex> lock(mutex);
            changed.wait(lock, [&] { return stopping || total >= 0 || taken - (bounded ? finished : integrated) < ahead; });
            if (stopping || total >= 0) return;
          }
          CpuLaps cpu;
          bool more = true;
          more = more && source->Next(&f);
          decode_ns += cpu.Lap();
          std::lock_guard<std::mutex> lock(mutex);
          if (!more) {
            if (total < 0) total = taken;
            changed.notify_all();
            return;
          }
          index = taken++;
          if (on_taken) on_taken(index);
        }
        auto prepared = mosaicker.Prepare(f.image, f.source, f.error);
        if (prepared) prepared->skipped_before = f.skipped_before;
        std::lock_guard<std::mutex> lock(mutex);
        ready[index] = std::move(prepared);
        changed.notify_all();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      if (!failure) failure = std::current_exception();
      stopping = true;
      changed.notify_all();
    }
  };
  std::vector<std::thread> preparers;
  for (int i = 0; i < workers; ++i) preparers.emplace_back(prepare_frames);
  auto stop = [&] {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stopping = true;
    }
    changed.notify_all();
    for (auto& t : preparers) t.join();
  };
  try {
    for (;;) {
      std::shared_ptr<PreparedFrame> next;
      {
        std::unique_lock<std::mutex> lock(mutex);
        const auto work = [&] { return failure || ready.count(integrated) || integrated == total; };
        // A live feed that pauses: what waits for a quiet moment (the preview of the last frames)
        // runs on this thread, where the engine may be called.
        while (on_idle && idle_s > 0 && !changed.wait_for(lock, std::chrono::duration<double>(idle_s), work)) {
          lock.unlock();
          on_idle();
          lock.lock();
        }
        changed.wait(lock, work);
        if (failure || integrated == total) break;
        next = std::move(ready[integrated]);
        ready.erase(integrated);
        ++integrated;
        changed.notify_all();
      }
      FrameReport r = mosaicker.Integrate(next);
      next.reset();
      if (on_frame) on_frame(r, source->count());
      {
        std::lock_guard<std::mutex> lock(mutex);
        ++finished;
      }
      changed.notify_all();
    }
  } catch (...) {
    stop();
    throw;
  }
  stop();
  if (failure) std::rethrow_exception(failure);
  return 1e-9 * static_cast<double>(decode_ns.load());
}

// MosaickerOptions::track_halve's "auto", decided by what the frames are.
std::string TrackHalving(const MosaickerOptions& options, const FrameSource& source) {
  if (options.track_halve != "auto") return options.track_halve;
  return source.coded_video() ? "always" : "never";
}

// The decoding time first among the stages: it is part of each frame's cost.
void AddDecodeStage(MosaicSummary* summary, double seconds) {
  summary->stage_seconds.insert(summary->stage_seconds.begin(), {"decode", seconds});
}

}  // namespace

void CheckMosaicInput(const std::string& input) { FrameSource::Open(input); }

MosaicSummary MosaicInput(const std::string& input, Store store, const MosaickerOptions& given,
                          const std::function<void(const FrameReport&, int)>& on_frame,
                          const std::atomic<bool>* stop, const std::function<void(const std::string&)>& on_note) {
  // Held before the calibration and the mask are written into the store, not from the engine on.
  const auto lock = LockStoreForChange(store, "a rolamos mosaic engine");
  std::string note;
  MosaickerOptions options = given.calibration == "auto" ? AutoCalibrate(input, store, given, &note) : given;
  std::string mask_note;
  const auto opened = FrameSource::Open(input);
  HeldSource source(opened.get());
  source.stop = stop;  // the overlay search reads up to 72 frames, and on (again) past a descent: a stop ends it too
  if (options.mask == "auto") options = AutoMask(&source, input, store, options, &mask_note, on_note);
  options.track_halve = TrackHalving(options, source);
  Mosaicker mosaicker(store, options);
  const double decode = RunPipeline(&source, mosaicker, on_frame, nullptr);
  MosaicSummary summary = mosaicker.Finish();
  summary.stopped = source.stopped();
  AddDecodeStage(&summary, decode);
  summary.calibration_note = note;
  summary.mask_note = mask_note;
  return summary;
}

// What needs the first frames before mapping (self-calibration, the overlay search) cannot wait
// for them live: an earlier run's results in the store are used. Without them self-calibration
// fails; the overlay search takes the live run's first frames, which wait in `feed` (every one
// kept) and are mapped first. When those cannot tell (a descent), it goes on over the frames as
// they come, a window ahead of the mapping (LookFurtherLive).
// Checked before the stream is opened.
MosaickerOptions LiveCalibration(MosaickerOptions options, const std::string& dir, std::string* note) {
  if (options.calibration != "auto") return options;
  if (!fs::exists(dir + "/calibration.yml"))
    Fail(dir, "has no calibration.yml from an earlier run; live mapping cannot self-calibrate first "
              "(give a calibration file, or none)");
  options.calibration = dir + "/calibration.yml";
  options.calibration_focal_measured = false;  // an earlier run's --calibration auto: assumed
  *note = "calibration from " + options.calibration;
  return options;
}

MosaickerOptions LiveMask(MosaickerOptions options, const Store& store, LiveSource* source, HeldSource* feed,
                          std::string* mask_note, bool* search_on) {
  *search_on = false;
  const std::string dir = store.dir();
  if (options.mask != "auto") return options;
  if (fs::exists(dir + "/static_mask.png")) {
    options.mask = dir + "/static_mask.png";
    *mask_note = "overlay mask from " + options.mask + " (found by an earlier run)";
    return options;
  }
  const StaticMaskOptions mo;
  std::vector<cv::Mat> images;
  // Held frames are beyond the backlog bound by design: none may be skipped while the search
  // gathers them (a burst of files on a loaded machine skipped some, and the search then waited
  // for frames that never came).
  source->CatchUp(mo.frames);
  while (static_cast<int>(feed->held()) < mo.frames) {
    const InputFrame* f = feed->HoldNext();
    if (!f) break;
    images.push_back(f->image);
  }
  StaticMask found = FindOverlay(images, options);
  found.note += " in the first " + std::to_string(images.size()) + " frames of the live run";
  options = UseOverlay(found, store, options, mask_note);
  // A descent through open water, a vehicle holding still: the frames after these may tell.
  *search_on = !found.conclusive && static_cast<int>(images.size()) >= mo.frames;
  source->CatchUp(mo.frames);  // what arrived meanwhile is mapped, not skipped
  return options;
}

// Live, after a first look that could not tell: the frames are read a window ahead of the mapping
// and looked at as they come (every 8, windows of 24, up to an hour at 30 frames/s: a live run
// reads nothing again, so only the 24 frames held ahead cost while it looks).
// The first window that tells gives the mapping its mask from that window's first frame on;
// the note says where it was found. The held frames cost memory (24 frames more) and latency (24
// frames later on the page) only while the search goes on.
void LookFurtherLive(HeldSource* feed, LiveSource* source, Mosaicker* mosaicker, const Store& store,
                     const MosaickerOptions& options, std::string* mask_note, std::unique_ptr<OverlayWindows>* keep) {
  OverlaySearchOptions search;
  search.max_frames = 108000;
  *keep = std::make_unique<OverlayWindows>(options, static_cast<int>(feed->held()), search);
  OverlayWindows* windows = keep->get();
  const std::string first = *mask_note;
  feed->look_ahead = StaticMaskOptions().frames;
  feed->look = [=](const InputFrame& f) {
    const bool looked = windows->Add(f.index, f.image);
    if (looked && windows->conclusive()) {
      const MosaickerOptions found = UseOverlay(windows->result(), store, options, mask_note);
      if (!found.mask.empty()) mosaicker->UseMask(found.mask);
    } else if (windows->exhausted()) {
      *mask_note = first + "; " + windows->FinalNote();
    } else {
      return;
    }
    // The frames read ahead are mapped now: what arrives meanwhile is mapped too, not skipped.
    source->CatchUp(feed->look_ahead);
    feed->look_ahead = 0;
  };
}

// The open patch for the page: the track and the current frame after every frame (written at
// most four times a second), the image every `every_s`, and at once for a new patch.
class PreviewOffers {
 public:
  PreviewOffers(const std::string& dir, double every_s) : every_s_(every_s) {
    if (every_s > 0) writer_.emplace(dir);
  }
  void After(const FrameReport& r, const Mosaicker& mosaicker) {
    if (!writer_) return;
    const auto now = std::chrono::steady_clock::now();
    const bool image = std::chrono::duration<double>(now - last_image_).count() >= every_s_ ||
                       (r.patch_id != writer_->imaged_patch() && r.patch_id > 0);
    if (image) last_image_ = now;
    stale_ = !image;
    writer_->Offer(mosaicker.Preview(0.5, 2.0, image));
  }
  // No frame for a while (a feed that pauses or ends): the image catches up with the last frames,
  // or the page would follow the vehicle beyond the seafloor it shows.
  void Idle(const Mosaicker& mosaicker) {
    if (!writer_ || !stale_) return;
    last_image_ = std::chrono::steady_clock::now();
    stale_ = false;
    writer_->Offer(mosaicker.Preview(0.5, 2.0, true));
  }
  double every_s() const { return writer_ ? every_s_ : 0; }
  // Writes the last one offered and says that no patch is open; returns what went wrong, if anything.
  std::string Close() {
    if (!writer_) return "";
    std::string problem = writer_->problem();
    writer_.reset();
    return problem;
  }

 private:
  double every_s_;
  bool stale_ = false;  // frames offered since the last image
  std::optional<LivePreviewWriter> writer_;
  std::chrono::steady_clock::time_point last_image_ = std::chrono::steady_clock::now();
};

MosaicSummary MosaicLive(const std::string& input, Store store, const MosaickerOptions& given,
                         const LiveOptions& live, const std::function<void(const LiveStatus&)>& on_status,
                         const std::function<void(const FrameReport&, int)>& on_frame) {
  const auto lock = LockStoreForChange(store, "a rolamos mosaic engine");  // before the mask is written
  const std::string dir = store.dir();
  std::string calibration_note, mask_note;
  MosaickerOptions options = LiveCalibration(given, dir, &calibration_note);
  auto source = LiveSource::Open(input, live);
  HeldSource feed(source.get());
  // From the first frame (the overlay search may hold the first ones a while), and before the
  // engine: its patch writer reports to it until the engine is gone.
  LiveStatusKeeper status(source.get(), live.max_waiting, on_status);
  bool search_on = false;
  options = LiveMask(options, store, source.get(), &feed, &mask_note, &search_on);
  options.track_halve = TrackHalving(options, *source);
  // Frames taken from the source and not yet mapped: with those waiting in the source, never
  // more than the backlog bound (the pipeline prepares at most one fewer ahead).
  std::atomic<long> in_flight{0};
  source->SetInFlight(&in_flight);
  feed.in_flight = &in_flight;
  Mosaicker mosaicker(store, options);
  std::unique_ptr<OverlayWindows> windows;
  if (search_on) LookFurtherLive(&feed, source.get(), &mosaicker, store, options, &mask_note, &windows);
  PreviewOffers preview(dir, live.preview_s);
  mosaicker.OnPatch([&](const PatchSidecar&) { status.PatchWritten(); });
  // Behind the feed, the engine describes fewer keyframes rather than skip frames.
  LoadShedding shed(live.max_waiting);
  // Only where it describes fewer than the options do: otherwise nothing would be shed, and the
  // status would say it was.
  const bool can_shed = live.shed_describe_overlap < options.describe_overlap;
  double decode = 0;
  MosaicSummary summary;
  try {
    decode = RunPipeline(
        &feed, mosaicker,
        [&](const FrameReport& r, int total) {
          --in_flight;
          const bool was_shedding = shed.on();
          if (can_shed && shed.Update(source->counters().waiting + static_cast<int>(in_flight)) != was_shedding)
            mosaicker.ShedLoad(shed.on(), live.shed_describe_overlap);
          status.Mapped(r, mosaicker.LastStepFraction(), was_shedding, shed.on());
          preview.After(r, mosaicker);
          if (on_frame) on_frame(r, total);
        },
        [&](long index) { status.Taken(index, feed.arrival()); }, std::max(1, live.max_waiting - 1),
        [&] { preview.Idle(mosaicker); }, preview.every_s());
    summary = mosaicker.Finish();
  } catch (const Error& e) {
    // A write failed (a full disk): what was written stays a valid store; say what it holds and
    // what was not saved, rather than only the failure.
    std::error_code ec;
    const auto space = fs::space(dir, ec);
    const bool full = !ec && space.available < (4u << 20);
    Fail(dir, std::string(e.what()) +
                  (full ? " (the disk is full: " + std::to_string(space.available >> 10) + " KiB free)" : "") +
                  "; the live run stopped there: the store holds the " + std::to_string(status.patches()) +
                  " patches written before (it opens and composes), the " + std::to_string(status.mapped()) +
                  " frames mapped since the run began were saved only as far as those patches go");
  }
  summary.preview_problem = preview.Close();
  AddDecodeStage(&summary, decode);
  status.Finish(summary);
  summary.calibration_note = calibration_note;
  summary.mask_note = mask_note;
  summary.frames_skipped = static_cast<int>(source->counters().skipped);
  summary.coverage_lost = static_cast<int>(status.coverage_lost());
  summary.frames_shedding = static_cast<int>(status.frames_shedding());
  return summary;
}

}  // namespace rolamos
