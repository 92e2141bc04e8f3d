#include "input/frame_source.h"

#include <algorithm>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>  // the IMREAD_ flags only: util/codecs.h reads
#include <opencv2/imgproc.hpp>

#include "input/jpeg_reader.h"
#include "rolamos/error.hpp"
#include "util/codecs.h"
#include "util/files.h"

namespace fs = std::filesystem;

namespace rolamos {

bool IsImageName(const std::string& name) {
  static const char* exts[] = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".ppm", ".pgm"};
  const std::string e = Extension(name);
  return std::any_of(std::begin(exts), std::end(exts), [&](const char* x) { return e == x; });
}

bool IsFolderFrame(const std::string& path) {
  const std::string name = fs::path(path).filename().string();
  return !name.empty() && name[0] != '.' && IsImageName(name);
}

namespace {

bool IsJpegName(const std::string& path) {
  const std::string ext = Extension(path);
  return ext == ".jpg" || ext == ".jpeg";
}

// Decoders fill a cut-off JPEG or PNG with grey and carry on; a frame like that would put a grey
// band into the mosaic. The end marker, in the file's last 64 bytes, tells. `head` is the file's
// first 4 bytes: a file not of the format at all is the decoder's to name ("unreadable").
bool EndMarkerMissing(bool jpeg, const std::string& head, const std::string& tail) {
  if (head.size() < 4) return false;
  if (jpeg) return head[0] == '\xFF' && head[1] == '\xD8' && tail.find("\xFF\xD9") == std::string::npos;
  return head.compare(1, 3, "PNG") == 0 && tail.find("IEND") == std::string::npos;
}

constexpr long long kTail = 64;

}  // namespace

bool LooksTruncated(const std::string& path) {
  const bool jpeg = IsJpegName(path), png = Extension(path) == ".png";
  if (!jpeg && !png) return false;
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  const auto size = static_cast<long long>(in.tellg());
  if (size < 4) return false;
  std::string head(4, '\0');
  in.seekg(0);
  in.read(head.data(), 4);
  const long long n = std::min<long long>(size, kTail);
  std::string tail(static_cast<size_t>(n), '\0');
  in.seekg(size - n);
  in.read(tail.data(), n);
  return EndMarkerMissing(jpeg, head, tail);
}

cv::Mat ToEightBit(const cv::Mat& image, std::atomic<int>* bits) {
  if (image.depth() == CV_8U || image.empty()) return image;
  cv::Mat out;
  if (image.depth() == CV_32F || image.depth() == CV_64F) {
    image.convertTo(out, CV_8U, 255.0);
    return out;
  }
  double most = 0;
  cv::minMaxLoc(image.reshape(1), nullptr, &most);
  int need = 8;
  while (need < 16 && most >= double(1 << need)) need += 2;
  int seen = bits->load();
  while (need > seen && !bits->compare_exchange_weak(seen, need)) {
  }
  const int use = std::max(need, seen);
  image.convertTo(out, CV_8U, 255.0 / double((1 << use) - 1));
  return out;
}

cv::Mat ReadFrameImage(const std::string& path, std::atomic<int>* bits, std::string* error) {
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    *error = "missing";
    return {};
  }
  const std::string truncated = "truncated (no end-of-image marker)";
  cv::Mat m;
  if (IsJpegName(path)) {
    // Read once: the end-marker check and the decoding look at the same bytes.
    std::string bytes;
    try {
      bytes = ReadSmallFile(path);
    } catch (const Error&) {
      bytes.clear();  // unreadable or huge: cv::imread below says which
    }
    if (!bytes.empty()) {
      const size_t n = std::min<size_t>(bytes.size(), kTail);
      if (EndMarkerMissing(true, bytes.substr(0, 4), bytes.substr(bytes.size() - n))) {
        *error = truncated;
        return {};
      }
      if (DecodeJpegBgr(bytes, &m)) return m;
    }
  } else if (LooksTruncated(path)) {
    *error = truncated;
    return {};
  }
  try {
    m = ToEightBit(ReadImageFile(path, cv::IMREAD_COLOR | cv::IMREAD_ANYDEPTH), bits);
  } catch (const cv::Exception& e) {
    *error = std::string("unreadable: ") + e.err;
    return {};
  }
  if (m.empty()) *error = "unreadable (not an image, or truncated)";
  return m;
}

int FrameSource::Take(int n, std::vector<InputFrame>* frames) {
  int read = 0;
  for (InputFrame f; read < n && Next(&f); ++read) frames->push_back(std::move(f));
  return read;
}

namespace {

class FileListSource : public FrameSource {
 public:
  explicit FileListSource(std::vector<std::string> paths) : paths_(std::move(paths)) {
    // Frames that are not JPEG are decoded by OpenCV's codecs: loaded here, before a store is made.
    if (!std::all_of(paths_.begin(), paths_.end(), IsJpegName)) RequireCodecs();
  }
  bool Next(InputFrame* f) override {
    if (next_ >= paths_.size()) return false;
    Read(next_++, f);
    return true;
  }
  int Take(int n, std::vector<InputFrame>* frames) override {
    const size_t first = frames->size(), count = std::min<size_t>(std::max(n, 0), paths_.size() - next_);
    frames->resize(first + count);
    cv::parallel_for_(cv::Range(0, static_cast<int>(count)), [&](const cv::Range& r) {
      for (int i = r.start; i < r.end; ++i) Read(next_ + size_t(i), &(*frames)[first + size_t(i)]);
    });
    next_ += count;
    return static_cast<int>(count);
  }
  int count() const override { return static_cast<int>(paths_.size()); }

 private:
  void Read(size_t i, InputFrame* f) const {
    f->index = static_cast<int>(i);
    f->source = paths_[i];
    f->error.clear();
    f->image = ReadFrameImage(paths_[i], &bits_, &f->error);
  }
  std::vector<std::string> paths_;
  size_t next_ = 0;
  mutable std::atomic<int> bits_{8};  // the depth the frames' values use (ToEightBit)
};

class VideoSource : public FrameSource {
 public:
  VideoSource(const std::string& path, std::unique_ptr<VideoReader> video) : path_(path), video_(std::move(video)) {
    count_ = static_cast<int>(video_->FrameCount());
  }
  bool Next(InputFrame* f) override {
    cv::Mat m;
    if (!video_->Read(&m)) return false;
    f->index = index_++;
    f->source = fs::path(path_).filename().string() + "#" + std::to_string(f->index);
    f->error.clear();
    if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
    f->image = m;
    return true;
  }
  int count() const override { return count_ > 0 ? count_ : -1; }
  bool coded_video() const override { return true; }

 private:
  std::string path_;
  std::unique_ptr<VideoReader> video_;
  int index_ = 0, count_ = -1;
};

}  // namespace

std::unique_ptr<FrameSource> FrameSource::Open(const std::string& input) {
  std::error_code ec;
  if (!fs::exists(input, ec)) Fail(input, "no such folder, list or video");
  if (fs::is_directory(input, ec)) {
    std::vector<std::string> paths;
    for (const auto& e : fs::directory_iterator(input, ec))
      if (e.is_regular_file() && IsFolderFrame(e.path().string())) paths.push_back(e.path().string());
    std::sort(paths.begin(), paths.end(), NaturalLess);
    if (paths.empty()) Fail(input, "holds no images (.jpg, .png, .tif, ...)");
    return std::make_unique<FileListSource>(std::move(paths));
  }
  if (Extension(input) == ".txt") {
    std::ifstream in(input);
    std::vector<std::string> paths;
    std::string line;
    while (std::getline(in, line)) {
      // Lists written by hand or by a spreadsheet: blanks and tabs around a name, Windows line ends.
      const size_t first = line.find_first_not_of(" \t\r"), last = line.find_last_not_of(" \t\r");
      line = first == std::string::npos ? "" : line.substr(first, last - first + 1);
      if (line.empty() || line[0] == '#') continue;
      fs::path p(line);
      paths.push_back(p.is_absolute() ? line : (fs::path(input).parent_path() / p).string());
    }
    if (paths.empty()) Fail(input, "lists no frames");
    return std::make_unique<FileListSource>(std::move(paths));
  }
  if (IsImageName(input)) Fail(input, "is a single image; give a folder, a list (.txt) or a video");
  std::unique_ptr<VideoReader> video;
  try {
    video = OpenVideo(input);
  } catch (const cv::Exception&) {
  }
  if (!video) Fail(input, "cannot be opened as a video (OpenCV/FFmpeg)");
  return std::make_unique<VideoSource>(input, std::move(video));
}

}  // namespace rolamos
