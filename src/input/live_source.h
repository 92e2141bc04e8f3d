// Frames as they arrive, for mapping live on the vehicle (`rolamos mosaic SOURCE --live`):
//  - a folder a logger writes into: new image files taken in name order as they appear, each
//    only once it is complete: closed by its writer or renamed into the folder (inotify, seen at
//    once), or, where the file system does not report it, its size unchanged over a listing;
//    and, for JPEG and PNG, its end-of-image marker written (one cut short whose size has not moved
//    for 3 s is taken as it is, counted as incomplete, and reported by the engine);
//  - a stream through OpenCV's GStreamer or FFmpeg back ends: a camera device (/dev/videoN), a
//    network URL (rtsp://, udp://, http://) or a GStreamer pipeline string (ending in appsink).
// When frames arrive faster than the engine takes them, the older waiting ones are skipped, so the
// map stays current instead of building a backlog: frames received and not yet mapped (waiting
// here, and taken but not yet mapped: SetInFlight) are at most `max_waiting`; when they arrive
// slower, none is skipped. The source ends at the end of the stream, when `stop` is set (SIGINT,
// SIGTERM: checked before any frame is taken, whatever the rate), or after `idle_timeout_s`
// without a new frame; a stream that stalls and comes back within it goes on, and one stalled
// for good does not hold up the end (its reader is left behind).
#pragma once

#include <atomic>
#include <algorithm>
#include <chrono>
#include <deque>
#include <vector>
#include <memory>
#include <string>

#include "input/frame_source.h"
#include "rolamos/mosaicker.hpp"  // LiveOptions

namespace rolamos {


// What a live source has seen so far (read from any thread).
struct LiveCounters {
  std::atomic<long long> received{0};  // frames that arrived
  std::atomic<long long> skipped{0};   // arrived and not mapped: skipped to keep up, or left by a stop
  std::atomic<double> last_arrival{0}; // Unix seconds of the newest frame
  std::atomic<long long> incomplete{0};  // files cut short and never finished, taken as they are
  // The most frames kept for mapping at once (waiting, and taken but not yet mapped), counted
  // after the skipping: never more than LiveOptions::max_waiting.
  std::atomic<int> backlog_max{0};
  // Frames waiting here now (after the skipping), as last counted: with those in flight, the
  // backlog the engine is behind by.
  std::atomic<int> waiting{0};
};

class LiveSource : public FrameSource {
 public:
  // Throws Error naming `input` when it is neither a folder nor a stream OpenCV opens.
  static std::unique_ptr<LiveSource> Open(const std::string& input, const LiveOptions& options);
  // Whether `input` names a stream (device, URL or pipeline) rather than a folder.
  static bool IsStream(const std::string& input);
  // A GStreamer pipeline whose udpsrc elements without a `buffer-size` are given one of
  // `bytes`. The kernel's default (~200 KB, rmem_default) holds two or three camera frames: a
  // pause of the vehicle's computer longer than that loses datagrams, hence frames, before
  // the engine could count them. The kernel caps the size at net.core.rmem_max.
  static std::string WithUdpReceiveBuffer(const std::string& pipeline, long bytes = 4 << 20);
  const LiveCounters& counters() const { return counters_; }
  // Arrival time (steady clock) of the frame Next returned last: for latency.
  std::chrono::steady_clock::time_point arrival() const { return arrival_; }
  int count() const override { return -1; }
  // Frames taken from the source and not yet mapped (kept by the caller): they count towards
  // the backlog the source keeps within `max_waiting`.
  // The source counts each frame it hands out there, under its own lock (no moment where a frame
  // taken is counted neither waiting nor in flight); the caller counts it down once mapped.
  void SetInFlight(std::atomic<long>* in_flight) { in_flight_ = in_flight; }
  // After frames were held at the start (the overlay search): the next `frames` frames taken are
  // kept beyond the bound, so those that arrived meanwhile are mapped rather than skipped.
  void CatchUp(int frames) { catch_up_ = std::max(0, frames); }
  // How many frames apart two frames may be and still overlap enough, at the vehicle's present
  // speed (from the engine after each frame); 0: unknown (the newest frames are kept).
  void SetMaxGap(int frames) { max_gap_ = std::max(0, frames); }

 protected:
  // Which of `waiting` frames (oldest first) to keep so the backlog stays within the bound: the
  // newest always; where the room allows, frames spaced at most SetMaxGap() apart from the last
  // one taken (a skipped frame then adds nothing the frames kept around it do not); then the
  // newest others.
  std::vector<bool> Keep(size_t waiting, int max_waiting) const;
  // Drops from `waiting` what Keep does not keep, counting them as skipped.
  template <class T>
  void Thin(std::deque<T>* waiting, int max_waiting) {
    const std::vector<bool> keep = Keep(waiting->size(), max_waiting);
    if (std::all_of(keep.begin(), keep.end(), [](bool k) { return k; })) return;
    std::deque<T> kept;
    for (size_t i = 0; i < keep.size(); ++i) {
      if (keep[i]) kept.push_back(std::move((*waiting)[i]));
      else ++counters_.skipped;
    }
    // Frames skipped right after the last one taken widen the first gap.
    for (size_t i = 0; i < keep.size() && !keep[i]; ++i) ++run_;
    *waiting = std::move(kept);
  }
  // Records the backlog once `waiting` frames wait here beside those in flight.
  void NoteBacklog(size_t waiting);
  // A frame taken (the catch-up counts down).
  void Took();
  // For the frame taken that came `seq`-th (0, 1, ... in the order frames arrived): how many
  // that came between it and the frame taken before were skipped.
  int SkippedBefore(long long seq);
  // Ends the source on a stop: the `waiting` frames are counted as skipped. Returns false.
  bool StopWith(size_t waiting);

  LiveCounters counters_;
  std::chrono::steady_clock::time_point arrival_{};
  std::atomic<long>* in_flight_ = nullptr;
  std::atomic<int> catch_up_{0};
  std::atomic<int> max_gap_{0};
  int run_ = 0;  // frames skipped since the last one taken (under the source's own lock)
  long long last_seq_ = -1;  // arrival number of the frame taken last
  bool stopped_ = false;
  int options_max_waiting_ = 1;  // set by the sources: LiveOptions::max_waiting
};

}  // namespace rolamos
