// Navigation for a live run's view: a vehicle navigation CSV (the columns `compose --navigation`
// reads) that the vehicle's logger keeps appending to. Re-read when it changes; a line that does
// not parse is skipped and reported once (file and line), and the run goes on; a last line not yet
// finished is read at the next change. The live view is georeferenced by the similarity that
// fits the frames' places in the view to their navigated places (server/live_view.h).
#pragma once

#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "rolamos/georeference.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct LiveNavigationOptions {
  std::string csv;       // the growing navigation CSV ("": none)
  std::string crs;       // EPSG:XXXX for eastings/northings without an epsg column
  double focal_px = 0;   // the camera's focal length in pixels; 0: from the store's camera
  bool IsValid(std::string* error) const;
};

class LiveNavigation {
 public:
  explicit LiveNavigation(LiveNavigationOptions options);
  // The navigation as the file now stands, for frames of `frame` size (the store's camera sets
  // the pixel size). Lines newly found bad are appended to `warnings`. Throws Error when the
  // file cannot be read at all or its header is wrong.
  std::map<std::string, FrameNavigation> Read(const Store& store, cv::Size frame, std::vector<std::string>* warnings);
  int lines_skipped() const;

 private:
  LiveNavigationOptions options_;
  mutable std::mutex mutex_;
  long long size_ = -1;
  long long mtime_ = 0;
  std::map<std::string, FrameNavigation> nav_;
  std::set<std::string> reported_;
};

// The focal length in pixels of the store's camera: its calibration file's, or from its field of
// view (70 degrees unless it says) and the frames' width.
double StoreFocalPx(const Store& store, cv::Size frame);

}  // namespace rolamos
