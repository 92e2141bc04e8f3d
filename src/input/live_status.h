// The counters of a live run as the viewer reads them (STORE/live/status.json, docs/store-format.md
// "live/"): frames received, mapped, rejected and skipped, the coverage the skips cost, the
// latency from a frame's arrival to its placement. They are handed to `on_status` after frames are
// mapped (at most every kStatusEvery) and on a heartbeat of their own, so the status follows the
// source while the engine is busy or the stream stalls. The keeper also tells the source how many
// frames it may skip at the vehicle's speed (LiveSource::SetMaxGap).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <thread>

#include "input/live_source.h"
#include "rolamos/mosaicker.hpp"

namespace rolamos {

class LiveStatusKeeper {
 public:
  static constexpr std::chrono::milliseconds kStatusEvery{500};

  // `source` outlives the keeper; `backlog_bound` is LiveOptions::max_waiting.
  LiveStatusKeeper(LiveSource* source, int backlog_bound, std::function<void(const LiveStatus&)> on_status);
  ~LiveStatusKeeper();
  LiveStatusKeeper(const LiveStatusKeeper&) = delete;
  LiveStatusKeeper& operator=(const LiveStatusKeeper&) = delete;

  // The `index`-th frame of the run was handed to the engine; it arrived at `arrived`.
  void Taken(long index, std::chrono::steady_clock::time_point arrived);
  // The engine placed or rejected the next frame in order; `step` is Mosaicker::LastStepFraction
  // after it (the vehicle's step between frames, as a fraction of the frame); `shedding`: the
  // frame was mapped while load was shed, and `shed_next` whether it is for the frames after it.
  void Mapped(const FrameReport& r, double step, bool shedding = false, bool shed_next = false);
  void PatchWritten();
  // The run ended: the engine's own counts (frames rejected at first and placed later count as
  // placed) and a last status that is not running. The heartbeat stops first. A keeper gone
  // without it (the run failed) writes a last status that is not running as well.
  void Finish(const MosaicSummary& summary);

  long mapped() const;
  int patches() const;
  long long coverage_lost() const;
  long long frames_shedding() const;

 private:
  void Report(bool running);  // under mutex_
  void StopHeartbeat();

  // The fraction of a frame the vehicle may move between two frames mapped one after the other.
  static constexpr double kMinOverlap = 0.6;

  LiveSource* source_;
  std::function<void(const LiveStatus&)> on_status_;
  mutable std::mutex mutex_;
  LiveStatus status_;
  std::map<long, std::chrono::steady_clock::time_point> arrivals_;
  std::deque<double> latencies_;  // ms, the last frames mapped
  long mapped_ = 0;
  long long skipped_before_ = 0;  // skips counted when the frame before was mapped
  std::chrono::steady_clock::time_point last_report_;
  std::condition_variable wake_;
  bool stopping_ = false;
  bool finished_ = false;  // Finish wrote the last status
  std::thread heartbeat_;
};

}  // namespace rolamos
