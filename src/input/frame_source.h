// Frames in order from a folder of images (sorted by name), a text list of paths, or a video.
// A frame that cannot be read comes back empty with the reason, so the pipeline can record it
// and go on.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct InputFrame {
  int index = 0;
  std::string source;  // file name, or "video.mp4#frame" for video frames
  cv::Mat image;       // BGR 8-bit; empty when unreadable
  std::string error;
  // Live: frames of the camera the source skipped just before this one (to keep up): the
  // vehicle moved that many frames' steps more since the frame before it.
  int skipped_before = 0;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // False at the end of the input.
  virtual bool Next(InputFrame* frame) = 0;
  // Up to `n` next frames at once, appended to `frames`; how many were read (fewer at the end).
  // Sources whose frames decode independently (image files) decode them in parallel: what reads
  // the first frames before mapping starts (the overlay search) need not wait on one core.
  virtual int Take(int n, std::vector<InputFrame>* frames);
  // Number of frames if known, -1 otherwise.
  virtual int count() const = 0;
  // Frames from a video codec (a video file, a camera or network stream), not still images.
  virtual bool coded_video() const { return false; }
  // Throws Error naming the input when it is none of the three kinds.
  static std::unique_ptr<FrameSource> Open(const std::string& input);
};

// Helpers shared with the live sources.
bool IsImageName(const std::string& name);
// A file a folder of frames contributes: an image by its extension, and not hidden. macOS leaves
// a "._NAME.jpg" (AppleDouble, not an image) beside every frame it copies onto a USB drive;
// editors and sync tools write hidden temporaries.
bool IsFolderFrame(const std::string& path);
// A JPEG or PNG whose end-of-image marker is missing (cut off, or still being written).
bool LooksTruncated(const std::string& path);
// Frames of more than 8 bits (16-bit PNG or TIFF from machine-vision cameras, which often hold
// 10 or 12 bits of data in 16) to 8 bits by the depth their values use: the fewest of 8, 10, 12,
// 14 or 16 bits that hold the largest value seen in the source so far (`bits`, only ever raised,
// so that a camera's frames keep one scale), not by the container's 16 (OpenCV's way, which
// leaves 12-bit data at 0..15: black). Float frames are taken as 0..1. 8-bit frames pass.
cv::Mat ToEightBit(const cv::Mat& image, std::atomic<int>* bits);
// BGR 8-bit (ToEightBit with the source's `bits`), or empty with the reason in `error`.
cv::Mat ReadFrameImage(const std::string& path, std::atomic<int>* bits, std::string* error);

}  // namespace rolamos
