#include "input/live_source.h"
#include "util/files.h"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>

#if defined(__linux__)
#include <poll.h>
#include <sys/inotify.h>
#include <unistd.h>
#endif

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>  // the CAP_ back ends only: util/codecs.h opens

#include "rolamos/error.hpp"
#include "util/clock.h"
#include "util/codecs.h"

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
  if (!(shed_describe_overlap > 0 && shed_describe_overlap <= 1)) {
    *error = "describe overlap while shedding load " + std::to_string(shed_describe_overlap) + " must be in (0, 1]";
    return false;
  }
  if (!(preview_s >= 0)) {
    *error = "preview interval " + std::to_string(preview_s) + " s cannot be negative";
    return false;
  }
  return true;
}

namespace {

bool Stopped(const LiveOptions& o) { return o.stop && o.stop->load(); }

// A folder that grows. New files are seen as their writers close them or as they are renamed
// into the folder (inotify), and by a listing every poll for file systems that do not report
// them (network mounts), where a file counts once its size held over a listing.
class GrowingFolderSource : public LiveSource {
 public:
  GrowingFolderSource(std::string dir, const LiveOptions& o) : dir_(std::move(dir)), options_(o) {
    options_max_waiting_ = o.max_waiting;
#if defined(__linux__)
    inotify_ = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    Watch();
#endif
  }
  ~GrowingFolderSource() override {
#if defined(__linux__)
    if (inotify_ >= 0) close(inotify_);
#endif
  }

  bool Next(InputFrame* f) override {
    auto idle_since = std::chrono::steady_clock::now();
    for (;;) {
      // A stop is honoured first, however fast frames arrive.
      if (Stopped(options_)) return StopWith(ready_.size());
      Collect();
      if (!ready_.empty()) {
        Thin(&ready_, options_.max_waiting);
        NoteBacklog(ready_.size());
        const auto [path, arrived, seq] = ready_.front();
        ready_.pop_front();
        f->index = index_++;
        f->skipped_before = SkippedBefore(seq);
        Took();
        f->source = path;
        f->error.clear();
        f->image = ReadFrameImage(path, &bits_, &f->error);
        arrival_ = arrived;
        return true;
      }
      if (options_.idle_timeout_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - idle_since).count() > options_.idle_timeout_s)
        return false;
      Wait();
    }
  }

 private:
  std::atomic<int> bits_{8};  // the depth the frames' values use (ToEightBit)

  // Until something may have arrived: an inotify event, or the next listing.
  void Wait() {
#if defined(__linux__)
    if (inotify_ >= 0) {
      pollfd p{inotify_, POLLIN, 0};
      poll(&p, 1, static_cast<int>(1000 * options_.poll_s));
      return;
    }
#endif
    std::this_thread::sleep_for(std::chrono::duration<double>(options_.poll_s));
  }

  // Files the file system reports complete (closed after writing, or moved in).
  // The folder watched once it exists (a logger may create it after the run starts).
  void Watch() {
#if defined(__linux__)
    if (inotify_ >= 0 && !watching_) {
      watching_ = inotify_add_watch(inotify_, dir_.c_str(), IN_CLOSE_WRITE | IN_MOVED_TO) >= 0;
      if (watching_) listed_ = {};  // list at once what came before the watch
    }
#endif
  }

  std::vector<std::string> Reported() {
    std::vector<std::string> out;
#if defined(__linux__)
    Watch();
    if (inotify_ < 0 || !watching_) return out;
    alignas(inotify_event) char buffer[16384];
    for (;;) {
      const ssize_t n = read(inotify_, buffer, sizeof buffer);
      if (n <= 0) break;
      for (ssize_t at = 0; at < n;) {
        const auto* e = reinterpret_cast<const inotify_event*>(buffer + at);
        if (e->len > 0 && !(e->mask & IN_ISDIR)) out.push_back((fs::path(dir_) / e->name).string());
        at += static_cast<ssize_t>(sizeof(inotify_event) + e->len);
      }
    }
#endif
    return out;
  }

  void Collect() {
    std::vector<std::string> complete;
    for (const auto& p : Reported())
      if (IsFolderFrame(p) && !taken_.count(p) && !LooksTruncated(p)) complete.push_back(p);
    const auto now = std::chrono::steady_clock::now();
    if (now - listed_ >= std::chrono::duration<double>(options_.poll_s)) {
      listed_ = now;
      std::error_code ec;
      std::map<std::string, uintmax_t> sizes;
      for (const auto& e : fs::directory_iterator(dir_, ec)) {
        const std::string p = e.path().string();
        if (!IsFolderFrame(p) || taken_.count(p)) continue;
        std::error_code ec2;
        if (!e.is_regular_file(ec2)) continue;
        sizes[p] = e.file_size(ec2);
      }
      // Complete: a JPEG or PNG whose end-of-image marker is written, at once; another format once
      // its size held since the last listing. With inotify this catches what it does not see (a
      // file there before the folder was watched), in the same pass as what it sees.
      // A file cut short (its writer died) stays unfinished: once its size has not moved for
      // kAbandonedS it is taken all the same, and the engine reports it (unreadable, or the part
      // that decodes), rather than it waiting unseen for ever.
      std::map<std::string, std::chrono::steady_clock::time_point> since;
      for (const auto& [p, size] : sizes) {
        auto it = seen_.find(p);
        const bool held = it != seen_.end() && it->second == size;
        auto s = unchanged_since_.find(p);
        since[p] = held && s != unchanged_since_.end() ? s->second : now;
        if (size == 0) continue;
        if (LooksTruncated(p)) {
          if (held && now - since[p] >= std::chrono::duration<double>(kAbandonedS)) {
            complete.push_back(p);
            ++counters_.incomplete;
          }
          continue;
        }
        const std::string ext = Extension(p);
        const bool marked = ext == ".jpg" || ext == ".jpeg" || ext == ".png";
        if (marked || held) complete.push_back(p);
      }
      seen_ = sizes;
      unchanged_since_ = since;
    }
    // In name order (NaturalLess: a logger's frame9 before its frame10), and never one that sorts
    // before a frame already taken (a late arrival of an older frame would go backwards in the survey).
    std::sort(complete.begin(), complete.end(), NaturalLess);
    complete.erase(std::unique(complete.begin(), complete.end()), complete.end());
    for (const auto& p : complete) {
      if (taken_.count(p)) continue;
      taken_.insert(p);
      seen_.erase(p);
      ++counters_.received;
      counters_.last_arrival = UnixNow();
      if (!last_.empty() && NaturalLess(p, last_)) {
        ++counters_.skipped;
        continue;
      }
      last_ = p;
      ready_.emplace_back(p, now, next_seq_++);
    }
  }

  std::string dir_;
  LiveOptions options_;
  int inotify_ = -1;
  bool watching_ = false;
  std::chrono::steady_clock::time_point listed_{};
  std::map<std::string, uintmax_t> seen_;  // not yet complete: size at the last listing
  std::map<std::string, std::chrono::steady_clock::time_point> unchanged_since_;  // and since when
  static constexpr double kAbandonedS = 3.0;
  std::set<std::string> taken_;
  // Complete frames waiting: path, arrival, and their number in the order they came.
  std::deque<std::tuple<std::string, std::chrono::steady_clock::time_point, long long>> ready_;
  long long next_seq_ = 0;
  std::string last_;
  int index_ = 0;
};

// A stream: a thread reads frames as fast as they come and keeps the newest; Next takes them.
// The reader shares its state rather than the source's: a read that never returns (a stalled
// stream) leaves the thread behind when the source ends, instead of holding up the end.
class StreamSource : public LiveSource {
 public:
  StreamSource(std::string name, std::unique_ptr<VideoReader> video, const LiveOptions& o)
      : name_(std::move(name)), options_(o), shared_(std::make_shared<Shared>()) {
    options_max_waiting_ = o.max_waiting;
    shared_->video = std::move(video);
    shared_->stop = o.stop;
    shared_->max_waiting = o.max_waiting;
    shared_->source = this;
    reader_ = std::thread([shared = shared_] { Read(shared); });
  }
  bool coded_video() const override { return true; }
  ~StreamSource() override {
    std::unique_lock<std::mutex> lock(shared_->mutex);
    shared_->source = nullptr;  // the reader no longer touches this source
    shared_->closing = true;
    shared_->changed.notify_all();
    // A reader blocked in a stalled read is left to finish on its own.
    const bool finished =
        shared_->changed.wait_for(lock, std::chrono::seconds(1), [&] { return shared_->finished; });
    lock.unlock();
    if (finished) reader_.join();
    else reader_.detach();
  }

  bool Next(InputFrame* f) override {
    std::unique_lock<std::mutex> lock(shared_->mutex);
    auto idle_since = std::chrono::steady_clock::now();
    for (;;) {
      if (Stopped(options_)) return StopWith(shared_->frames.size());
      if (!shared_->frames.empty()) break;
      if (shared_->ended) return false;
      shared_->changed.wait_for(lock, std::chrono::milliseconds(100));
      if (shared_->frames.empty() && options_.idle_timeout_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - idle_since).count() > options_.idle_timeout_s)
        return false;
    }
    Thin(&shared_->frames, options_.max_waiting);
    NoteBacklog(shared_->frames.size());
    auto [image, arrived, seq] = std::move(shared_->frames.front());
    shared_->frames.pop_front();
    f->index = index_++;
    f->skipped_before = SkippedBefore(seq);
    Took();
    // Named by its number in the stream, skipped frames counted: where it is in the recording.
    f->source = name_ + "#" + std::to_string(seq);
    f->error.clear();
    f->image = image;
    arrival_ = arrived;
    return true;
  }

 private:
  struct Shared {
    std::unique_ptr<VideoReader> video;
    std::mutex mutex;
    std::condition_variable changed;
    // Frames waiting: image, arrival, and their number in the order they came.
    std::deque<std::tuple<cv::Mat, std::chrono::steady_clock::time_point, long long>> frames;
    long long next_seq = 0;
    const std::atomic<bool>* stop = nullptr;
    int max_waiting = 1;
    StreamSource* source = nullptr;  // set while the source lives (its counters)
    bool ended = false, closing = false, finished = false;
  };

  static void Read(std::shared_ptr<Shared> s) {
    for (;;) {
      cv::Mat m;
      bool ok = false;
      try {
        ok = s->video->Read(&m);
      } catch (const cv::Exception&) {
        ok = false;
      }
      std::lock_guard<std::mutex> lock(s->mutex);
      if (s->closing || (s->stop && s->stop->load())) break;
      if (!ok) {
        s->ended = true;  // the end of the stream (a stall only blocks read)
        break;
      }
      if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
      if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
      if (s->source) {
        ++s->source->counters_.received;
        s->source->counters_.last_arrival = UnixNow();
      }
      s->frames.emplace_back(m, std::chrono::steady_clock::now(), s->next_seq++);
      // Frames keep arriving while nothing takes them: the backlog stays within the bound.
      if (s->source) s->source->Thin(&s->frames, s->max_waiting);
      if (s->source) s->source->NoteBacklog(s->frames.size());
      s->changed.notify_all();
    }
    std::lock_guard<std::mutex> lock(s->mutex);
    s->finished = true;
    s->changed.notify_all();
  }

  std::string name_;
  LiveOptions options_;
  std::shared_ptr<Shared> shared_;
  std::thread reader_;
  int index_ = 0;
};

}  // namespace

std::vector<bool> LiveSource::Keep(size_t waiting, int max_waiting) const {
  const long in_flight = in_flight_ ? std::max(0L, in_flight_->load()) : 0;
  const long room = std::max(1L, static_cast<long>(max_waiting) + catch_up_.load() - in_flight);
  const long n = static_cast<long>(waiting);
  std::vector<bool> keep(waiting, n <= room);
  if (n <= room) return keep;
  keep[size_t(n - 1)] = true;  // the newest: the one the map needs
  long slots = room - 1;
  // Stepping stones from the last frame taken, each as far as still overlaps the one before.
  if (const long gap = max_gap_.load(); gap > 0) {
    long prev = -1 - run_;  // the last frame taken
    while (slots > 0 && n - 1 - prev > gap) {
      const long at = std::max(prev + gap, 0L);
      if (at >= n - 1) break;
      keep[size_t(at)] = true;
      --slots;
      prev = at;
    }
  }
  for (long i = n - 2; i >= 0 && slots > 0; --i)
    if (!keep[size_t(i)]) keep[size_t(i)] = true, --slots;
  return keep;
}

bool LiveSource::StopWith(size_t waiting) {
  // Frames that arrived and will not be mapped: counted with the skipped, never dropped unsaid.
  if (!stopped_) counters_.skipped += static_cast<long long>(waiting);
  stopped_ = true;
  return false;
}

int LiveSource::SkippedBefore(long long seq) {
  const long long skipped = last_seq_ < 0 ? 0 : std::max(0LL, seq - last_seq_ - 1);
  last_seq_ = seq;
  return static_cast<int>(std::min<long long>(skipped, 1 << 20));
}

void LiveSource::Took() {
  run_ = 0;
  --counters_.waiting;  // the frame taken was among those NoteBacklog counted
  if (in_flight_) ++*in_flight_;
  int left = catch_up_.load();
  while (left > 0 && !catch_up_.compare_exchange_weak(left, left - 1)) {
  }
}

void LiveSource::NoteBacklog(size_t waiting) {
  const long in_flight = in_flight_ ? std::max(0L, in_flight_->load()) : 0;
  const int backlog = static_cast<int>(in_flight + static_cast<long>(waiting));
  counters_.waiting = static_cast<int>(waiting);
  if (catch_up_ > 0 && backlog > options_max_waiting_) return;  // catching up: beyond the bound by design
  int seen = counters_.backlog_max.load();
  while (backlog > seen && !counters_.backlog_max.compare_exchange_weak(seen, backlog)) {
  }
}

bool LiveSource::IsStream(const std::string& input) {
  return input.rfind("/dev/video", 0) == 0 || input.find("://") != std::string::npos ||
         input.find(" ! ") != std::string::npos;
}

std::string LiveSource::WithUdpReceiveBuffer(const std::string& pipeline, long bytes) {
  const std::string name = "udpsrc";
  std::string out;
  size_t from = 0;
  for (size_t at; (at = pipeline.find(name, from)) != std::string::npos;) {
    const size_t after = at + name.size();
    out += pipeline.substr(from, after - from);
    from = after;
    const bool element = (at == 0 || pipeline[at - 1] == ' ' || pipeline[at - 1] == '!') &&
                         (after == pipeline.size() || pipeline[after] == ' ' || pipeline[after] == '!');
    const size_t end = std::min(pipeline.find('!', after), pipeline.size());  // its properties
    if (element && pipeline.substr(after, end - after).find("buffer-size=") == std::string::npos)
      out += " buffer-size=" + std::to_string(bytes);
  }
  return out + pipeline.substr(from);
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
  std::unique_ptr<VideoReader> video;
  try {
    if (input.find(" ! ") != std::string::npos) video = OpenVideo(WithUdpReceiveBuffer(input), cv::CAP_GSTREAMER);
    else if (input.rfind("/dev/video", 0) == 0) video = OpenVideo(input, cv::CAP_V4L2);
    else video = OpenVideo(input, cv::CAP_FFMPEG);
    if (!video && input.find(" ! ") == std::string::npos) video = OpenVideo(input);  // any back end
  } catch (const cv::Exception& e) {
    Fail(input, std::string("cannot be opened as a stream: ") + e.err);
  }
  if (!video) Fail(input, "cannot be opened as a stream by OpenCV's GStreamer, V4L2 or FFmpeg back ends");
  std::string name = input.rfind("/dev/video", 0) == 0 ? fs::path(input).filename().string() : "stream";
  return std::make_unique<StreamSource>(name, std::move(video), options);
}

}  // namespace rolamos
