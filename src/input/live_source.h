// Frames as they arrive, for mapping live on the vehicle (`rolamos mosaic SOURCE --live`):
//  - a folder a logger writes into: new image files taken in name order as they appear, each
//    only once it is complete (its size unchanged over one poll and, for JPEG and PNG, its
//    end-of-image marker written);
//  - a stream through OpenCV's GStreamer or FFmpeg back ends: a camera device (/dev/videoN), a
//    network URL (rtsp://, udp://, http://) or a GStreamer pipeline string (ending in appsink).
// When frames arrive faster than the engine takes them, the older waiting ones are skipped, so the
// map stays current instead of building a backlog; when they arrive slower, none is skipped.
// The source ends at the end of the stream, when `stop` is set (SIGINT, SIGTERM), or after
// `idle_timeout_s` without a new frame; a stream that stalls and comes back within it goes on.
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <string>

#include "input/frame_source.h"
#include "rolamos/mosaicker.hpp"  // LiveOptions

namespace rolamos {


// What a live source has seen so far (read from any thread).
struct LiveCounters {
  std::atomic<long long> received{0};  // frames that arrived
  std::atomic<long long> skipped{0};   // arrived but skipped to keep up
  std::atomic<double> last_arrival{0}; // Unix seconds of the newest frame
};

class LiveSource : public FrameSource {
 public:
  // Throws Error naming `input` when it is neither a folder nor a stream OpenCV opens.
  static std::unique_ptr<LiveSource> Open(const std::string& input, const LiveOptions& options);
  // Whether `input` names a stream (device, URL or pipeline) rather than a folder.
  static bool IsStream(const std::string& input);
  const LiveCounters& counters() const { return counters_; }
  // Arrival time (steady clock) of the frame Next returned last: for latency.
  std::chrono::steady_clock::time_point arrival() const { return arrival_; }
  int count() const override { return -1; }

 protected:
  LiveCounters counters_;
  std::chrono::steady_clock::time_point arrival_{};
};

}  // namespace rolamos
