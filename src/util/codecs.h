// Image files and video through OpenCV's imgcodecs and videoio, loaded when first needed.
// Programs linked with the whole library (the full module, the tests, Python) have them linked in
// (codecs_opencv.cc); the `rolamos` launcher finds them in the full module (util/full_module.h),
// so that a run over JPEG frames (input/jpeg_reader: libjpeg) never loads them.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// cv::imread.
cv::Mat ReadImageFile(const std::string& path, int flags);
// cv::imencode: false when OpenCV cannot encode `image` as `extension` (".png").
bool EncodeImage(const std::string& extension, const cv::Mat& image, std::vector<unsigned char>* bytes);

// An open video file, device or stream (cv::VideoCapture).
class VideoReader {
 public:
  virtual ~VideoReader() = default;
  // The next frame; false at the end or on a read error.
  virtual bool Read(cv::Mat* frame) = 0;
  // As the container says (0 or less when it does not).
  virtual double FrameCount() const = 0;
};
// `api` is one of cv::VideoCaptureAPIs (0: any back end). nullptr when none opens `name`; a back end
// that rejects it may throw cv::Exception.
std::unique_ptr<VideoReader> OpenVideo(const std::string& name, int api = 0);

// Loads them now (the launcher: from the full module) when they are not linked in: a run that
// will need them fails before it writes anything when they cannot be loaded. Throws Error.
void RequireCodecs();

// The codecs a program provides (codecs_opencv.cc, registered when it is linked in).
struct CodecTable {
  cv::Mat (*read_image)(const std::string& path, int flags);
  bool (*encode_image)(const std::string& extension, const cv::Mat& image, std::vector<unsigned char>* bytes);
  std::unique_ptr<VideoReader> (*open_video)(const std::string& name, int api);
};
void ProvideCodecs(const CodecTable* table);
// True when this program has them linked in (false in the launcher until the module is loaded).
bool CodecsLinkedIn();

}  // namespace rolamos

// The table, as the full module exports it (C linkage, for dlsym).
extern "C" const rolamos::CodecTable* rolamos_codecs();
