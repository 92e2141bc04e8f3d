#include "input/live_source.h"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "rolamos/error.hpp"

namespace fs = std::filesystem;

namespace rolamos {

bool LiveOptions::IsValid(std::string* error) const {
  if (!(idle_timeout_s >= 0)) {
    *error = "idle timeout " + std::to_string(idle_timeout_s) + " s cannot be negative";
    return false;
  }
  if (!(poll_s > 0 && poll_s <= 10)) {
    *error = "poll interval " + std::to_string(poll_s) + " s must be in (0, 10]";
    return false;
  }
  if (max_waiting < 1) {
    *error = "frames allowed to wait must be at least 1";
    return false;
  }
  return true;
}

namespace {

double UnixNow() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

bool Stopped(const LiveOptions& o) { return o.stop && o.stop->load(); }

// A folder that grows: listed every poll; a file counts once its size has held for a poll.
class GrowingFolderSource : public LiveSource {
 public:
  GrowingFolderSource(std::string dir, const LiveOptions& o) : dir_(std::move(dir)), options_(o) {}

  bool Next(InputFrame* f) override {
    auto idle_since = std::chrono::steady_clock::now();
    for (;;) {
      Poll();
      if (!ready_.empty()) {
        // Keep up: only the newest frames wait; the rest are skipped.
        while (static_cast<int>(ready_.size()) > options_.max_waiting) {
          ready_.pop_front();
          ++counters_.skipped;
        }
        const auto [path, arrived] = ready_.front();
        ready_.pop_front();
        f->index = index_++;
        f->source = path;
        f->error.clear();
        f->image = ReadFrameImage(path, &f->error);
        arrival_ = arrived;
        return true;
      }
      if (Stopped(options_)) return false;
      if (options_.idle_timeout_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - idle_since).count() > options_.idle_timeout_s)
        return false;
      std::this_thread::sleep_for(std::chrono::duration<double>(options_.poll_s));
    }
  }

 private:
  void Poll() {
    std::error_code ec;
    std::map<std::string, uintmax_t> sizes;
    for (const auto& e : fs::directory_iterator(dir_, ec)) {
      const std::string p = e.path().string();
      if (!IsImageName(p) || taken_.count(p)) continue;
      std::error_code ec2;
      if (!e.is_regular_file(ec2)) continue;
      sizes[p] = e.file_size(ec2);
    }
    // Complete: the size held since the last poll (and an end marker where the format has one).
    std::vector<std::string> complete;
    for (const auto& [p, size] : sizes) {
      auto it = seen_.find(p);
      if (it != seen_.end() && it->second == size && size > 0 && !LooksTruncated(p)) complete.push_back(p);
    }
    seen_ = sizes;
    // In name order, and never one that sorts before a frame already taken (a late arrival of an
    // older frame would go backwards in the survey).
    std::sort(complete.begin(), complete.end());
    const auto now = std::chrono::steady_clock::now();
    for (const auto& p : complete) {
      taken_.insert({p, true});
      seen_.erase(p);
      ++counters_.received;
      counters_.last_arrival = UnixNow();
      if (!last_.empty() && p < last_) {
        ++counters_.skipped;
        continue;
      }
      last_ = p;
      ready_.emplace_back(p, now);
    }
  }

  std::string dir_;
  LiveOptions options_;
  std::map<std::string, uintmax_t> seen_;  // not yet complete: size at the last poll
  std::map<std::string, bool> taken_;
  std::deque<std::pair<std::string, std::chrono::steady_clock::time_point>> ready_;
  std::string last_;
  int index_ = 0;
};

// A stream: a thread reads frames as fast as they come and keeps the newest; Next takes it.
class StreamSource : public LiveSource {
 public:
  StreamSource(std::string name, cv::VideoCapture cap, const LiveOptions& o)
      : name_(std::move(name)), cap_(std::move(cap)), options_(o) {
    reader_ = std::thread([this] { Read(); });
  }
  ~StreamSource() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closing_ = true;
    }
    changed_.notify_all();
    if (reader_.joinable()) reader_.join();
  }

  bool Next(InputFrame* f) override {
    std::unique_lock<std::mutex> lock(mutex_);
    auto idle_since = std::chrono::steady_clock::now();
    for (;;) {
      if (!frames_.empty()) break;
      if (ended_ || Stopped(options_)) return false;
      changed_.wait_for(lock, std::chrono::milliseconds(100));
      if (frames_.empty() && options_.idle_timeout_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - idle_since).count() > options_.idle_timeout_s)
        return false;
    }
    auto [image, arrived] = std::move(frames_.front());
    frames_.pop_front();
    f->index = index_++;
    f->source = name_ + "#" + std::to_string(f->index);
    f->error.clear();
    f->image = image;
    arrival_ = arrived;
    return true;
  }

 private:
  void Read() {
    for (;;) {
      cv::Mat m;
      bool ok = false;
      try {
        ok = cap_.read(m) && !m.empty();
      } catch (const cv::Exception&) {
        ok = false;
      }
      std::lock_guard<std::mutex> lock(mutex_);
      if (closing_ || Stopped(options_)) break;
      if (!ok) {
        ended_ = true;  // the end of the stream (a stall only blocks read)
        break;
      }
      if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
      if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
      ++counters_.received;
      counters_.last_arrival = UnixNow();
      frames_.emplace_back(m, std::chrono::steady_clock::now());
      while (static_cast<int>(frames_.size()) > options_.max_waiting) {
        frames_.pop_front();
        ++counters_.skipped;
      }
      changed_.notify_all();
    }
    changed_.notify_all();
  }

  std::string name_;
  cv::VideoCapture cap_;
  LiveOptions options_;
  std::thread reader_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::pair<cv::Mat, std::chrono::steady_clock::time_point>> frames_;
  bool ended_ = false, closing_ = false;
  int index_ = 0;
};

}  // namespace

bool LiveSource::IsStream(const std::string& input) {
  return input.rfind("/dev/video", 0) == 0 || input.find("://") != std::string::npos ||
         input.find(" ! ") != std::string::npos;
}

std::unique_ptr<LiveSource> LiveSource::Open(const std::string& input, const LiveOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) Fail(input, error);
  std::error_code ec;
  if (!IsStream(input)) {
    if (!fs::is_directory(input, ec))
      Fail(input, "is neither a folder to watch nor a stream (/dev/videoN, rtsp://, udp://, or a GStreamer "
                  "pipeline ending in appsink)");
    return std::make_unique<GrowingFolderSource>(input, options);
  }
  cv::VideoCapture cap;
  try {
    if (input.find(" ! ") != std::string::npos) cap.open(input, cv::CAP_GSTREAMER);
    else if (input.rfind("/dev/video", 0) == 0) cap.open(input, cv::CAP_V4L2);
    else cap.open(input, cv::CAP_FFMPEG);
    if (!cap.isOpened() && input.find(" ! ") == std::string::npos) cap.open(input);  // any back end
  } catch (const cv::Exception& e) {
    Fail(input, std::string("cannot be opened as a stream: ") + e.err);
  }
  if (!cap.isOpened()) Fail(input, "cannot be opened as a stream by OpenCV's GStreamer, V4L2 or FFmpeg back ends");
  std::string name = input.rfind("/dev/video", 0) == 0 ? fs::path(input).filename().string() : "stream";
  return std::make_unique<StreamSource>(name, std::move(cap), options);
}

}  // namespace rolamos
