// The open patch of a live run, written for the viewer while it grows (docs/store-format.md,
// "live/"): STORE/live/preview-NNNNNN.tif, a small pyramidal tiled TIFF of the working canvas
// (WebP with alpha), and STORE/live/preview.json that names the newest one with the track, the
// current frame's footprint and how the patch joins the one before. Each version has a name of its
// own, so a server reading one never sees it change under it; the last few are kept, older ones
// removed. Encoding and writing run on a thread of their own: the engine only renders the canvas.
#pragma once

#include <condition_variable>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "rolamos/mosaicker.hpp"

namespace rolamos {

class LivePreviewWriter {
 public:
  explicit LivePreviewWriter(std::string store_dir);
  ~LivePreviewWriter();  // writes what was offered last, then says that no patch is open
  LivePreviewWriter(const LivePreviewWriter&) = delete;
  LivePreviewWriter& operator=(const LivePreviewWriter&) = delete;

  // The newest preview replaces one not yet written (the page wants the current state only); at
  // most four are written a second, the last one always. One without an image updates the track
  // and footprint beside the last image of the same patch.
  void Offer(LivePreview preview);
  // The patch of the last image offered (0: none): a new patch needs its image at once.
  int imaged_patch() const { return imaged_patch_; }
  // Problems writing (a full disk): the run goes on without previews, and says so once.
  std::string problem() const;

 private:
  void Run();
  void Write(const LivePreview& p, int image_frames);  // the patch's frames when the image was rendered

  std::string dir_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::optional<LivePreview> pending_;
  int pending_image_frames_ = 0;  // the frames placed when pending_'s image was rendered
  int imaged_patch_ = 0;   // Offer's thread
  // The last image written (writer's thread): what a preview without one is shown with.
  struct Written {
    int patch = 0;
    std::string image;
    int width = 0, height = 0;
    int frames = 0;  // the patch's frames placed when it was rendered
    cv::Matx33d patch_to_image = cv::Matx33d::eye();
  } written_;
  bool closing_ = false;
  long long version_ = 0;
  std::string problem_;
  std::thread thread_;
};

}  // namespace rolamos
