// OpenCV's imgcodecs and videoio behind util/codecs.h. Not in the core library: linked into the
// programs that may load them at start (see CMakeLists.txt, rolamos_codecs).
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "util/codecs.h"

namespace rolamos {
namespace {

class CaptureReader : public VideoReader {
 public:
  explicit CaptureReader(cv::VideoCapture cap) : cap_(std::move(cap)) {}
  bool Read(cv::Mat* frame) override { return cap_.read(*frame) && !frame->empty(); }
  double FrameCount() const override { return cap_.get(cv::CAP_PROP_FRAME_COUNT); }

 private:
  cv::VideoCapture cap_;
};

cv::Mat Read(const std::string& path, int flags) { return cv::imread(path, flags); }

bool Encode(const std::string& extension, const cv::Mat& image, std::vector<unsigned char>* bytes) {
  try {
    return cv::imencode(extension, image, *bytes);
  } catch (const cv::Exception&) {  // no encoder for the extension, or not for this image's type
    return false;
  }
}

std::unique_ptr<VideoReader> Open(const std::string& name, int api) {
  cv::VideoCapture cap;
  cap.open(name, api);  // a cv::Exception of a back end that rejects the name goes to the caller
  if (!cap.isOpened()) return nullptr;
  return std::make_unique<CaptureReader>(std::move(cap));
}

const CodecTable kOpenCvCodecs{&Read, &Encode, &Open};
const bool kRegistered = (ProvideCodecs(&kOpenCvCodecs), true);

}  // namespace
}  // namespace rolamos

extern "C" const rolamos::CodecTable* rolamos_codecs() { return &rolamos::kOpenCvCodecs; }
