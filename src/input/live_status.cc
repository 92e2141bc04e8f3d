#include "input/live_status.h"

#include <algorithm>
#include <vector>

#include "util/clock.h"

namespace rolamos {

namespace {

constexpr size_t kLatencyWindow = 600;  // frames

}  // namespace

LiveStatusKeeper::LiveStatusKeeper(LiveSource* source, int backlog_bound, std::function<void(const LiveStatus&)> on_status)
    : source_(source), on_status_(std::move(on_status)) {
  status_.started = UnixNow();
  status_.backlog_bound = backlog_bound;
  std::lock_guard<std::mutex> lock(mutex_);
  Report(true);
  // Frames arrive while the engine is busy, and a stream stalls right after a frame was mapped:
  // without a beat of its own the status lagged the frames received by up to kStatusEvery (five
  // frames of a stalled 10 frames/s stream).
  heartbeat_ = std::thread([this] {
    std::unique_lock<std::mutex> lock(mutex_);
    while (!wake_.wait_for(lock, kStatusEvery, [this] { return stopping_; })) {
      const LiveCounters& c = source_->counters();
      if (c.received == status_.frames_received && c.skipped == status_.frames_skipped) continue;
      try {
        Report(true);
      } catch (...) {
        // Writing the status is the caller's to report; this thread must not end the run.
      }
    }
  });
}

LiveStatusKeeper::~LiveStatusKeeper() {
  StopHeartbeat();
  if (finished_) return;
  // The run ended without Finish (an error): the page must not show it running.
  try {
    std::lock_guard<std::mutex> lock(mutex_);
    Report(false);
  } catch (...) {
  }
}

void LiveStatusKeeper::StopHeartbeat() {
  if (!heartbeat_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  heartbeat_.join();
}

void LiveStatusKeeper::Report(bool running) {
  const LiveCounters& c = source_->counters();
  status_.running = running;
  status_.frames_received = c.received;
  status_.frames_skipped = c.skipped;
  status_.backlog_max = c.backlog_max;
  status_.frames_incomplete = c.incomplete;
  status_.last_frame_time = c.last_arrival;
  if (!latencies_.empty()) {
    std::vector<double> l(latencies_.begin(), latencies_.end());
    std::sort(l.begin(), l.end());
    status_.latency_ms_p50 = l[l.size() / 2];
    status_.latency_ms_p95 = l[std::min(l.size() - 1, l.size() * 95 / 100)];
  }
  status_.updated = UnixNow();
  last_report_ = std::chrono::steady_clock::now();
  if (on_status_) on_status_(status_);
}

void LiveStatusKeeper::Taken(long index, std::chrono::steady_clock::time_point arrived) {
  std::lock_guard<std::mutex> lock(mutex_);
  arrivals_[index] = arrived;
}

void LiveStatusKeeper::Mapped(const FrameReport& r, double step, bool shedding, bool shed_next) {
  std::lock_guard<std::mutex> lock(mutex_);
  status_.frames_shedding += shedding;
  status_.shedding = shed_next;
  const auto now = std::chrono::steady_clock::now();
  if (auto it = arrivals_.find(mapped_); it != arrivals_.end()) {
    latencies_.push_back(1e3 * std::chrono::duration<double>(now - it->second).count());
    if (latencies_.size() > kLatencyWindow) latencies_.pop_front();
    arrivals_.erase(it);
  }
  ++mapped_;
  // Frames were skipped before this one, and it does not join the frame before it.
  const long long skipped = source_->counters().skipped;
  if (skipped > skipped_before_ && !r.continues) ++status_.coverage_lost;
  // What the source may skip at the vehicle's speed and keep each frame overlapping the one
  // before by kMinOverlap (the step measured over the camera frames it spans).
  if (step > 0 && r.continues) {
    const double per_frame = step / double(1 + skipped - skipped_before_);
    source_->SetMaxGap(static_cast<int>(std::clamp((1 - kMinOverlap) / per_frame, 1.0, 1000.0)));
  }
  skipped_before_ = skipped;
  if (r.status == "stitched") ++status_.frames_registered;
  else ++status_.frames_rejected;
  status_.open_patch = r.patch_id;
  if (now - last_report_ > kStatusEvery) Report(true);
}

void LiveStatusKeeper::PatchWritten() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++status_.patches;
  Report(true);
}

void LiveStatusKeeper::Finish(const MosaicSummary& summary) {
  StopHeartbeat();
  std::lock_guard<std::mutex> lock(mutex_);
  finished_ = true;
  status_.shedding = false;
  status_.open_patch = 0;
  status_.frames_registered = summary.stitched;
  status_.frames_rejected = summary.rejected;
  Report(false);
}

long long LiveStatusKeeper::frames_shedding() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_.frames_shedding;
}

long LiveStatusKeeper::mapped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return mapped_;
}

int LiveStatusKeeper::patches() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_.patches;
}

long long LiveStatusKeeper::coverage_lost() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_.coverage_lost;
}

}  // namespace rolamos
