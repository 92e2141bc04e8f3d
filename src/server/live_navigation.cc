#include "server/live_navigation.h"

#include <cmath>
#include <filesystem>

#include "engine/preprocess.h"
#include "rolamos/error.hpp"

namespace rolamos {

bool LiveNavigationOptions::IsValid(std::string* error) const {
  if (focal_px < 0 || !std::isfinite(focal_px)) {
    *error = "focal length " + std::to_string(focal_px) + " px cannot be negative";
    return false;
  }
  return true;
}

LiveNavigation::LiveNavigation(LiveNavigationOptions options) : options_(std::move(options)) {
  std::string error;
  if (!options_.IsValid(&error)) Fail(options_.csv, error);
}

double StoreFocalPx(const Store& store, cv::Size frame) {
  const nlohmann::json camera = store.camera();
  if (camera.is_object() && camera.contains("calibration_file"))
    return ReadCalibration(camera["calibration_file"].get<std::string>()).camera_matrix(0, 0);
  const double fov = camera.is_object() ? camera.value("fov_deg", 70.0) : 70.0;
  return 0.5 * frame.width / std::tan(0.5 * fov * CV_PI / 180);
}

std::map<std::string, FrameNavigation> LiveNavigation::Read(const Store& store, cv::Size frame,
                                                            std::vector<std::string>* warnings) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::error_code ec;
  const auto size = static_cast<long long>(std::filesystem::file_size(options_.csv, ec));
  if (ec) Fail(options_.csv, "cannot be read: " + ec.message());
  const auto mtime = static_cast<long long>(std::filesystem::last_write_time(options_.csv, ec).time_since_epoch().count());
  if (size == size_ && mtime == mtime_) return nav_;
  if (frame.width <= 0 || frame.height <= 0) return nav_;  // no frame yet: the pixel size is not known
  NavigationCamera camera;
  camera.focal_px = options_.focal_px > 0 ? options_.focal_px : StoreFocalPx(store, frame);
  camera.width = frame.width;
  camera.height = frame.height;
  std::vector<std::string> skipped;
  nav_ = ReadNavigationCsv(options_.csv, camera, options_.crs, &skipped);
  size_ = size;
  mtime_ = mtime;
  for (const auto& s : skipped)
    if (reported_.insert(s).second && warnings) warnings->push_back(s);
  return nav_;
}

int LiveNavigation::lines_skipped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int>(reported_.size());
}

}  // namespace rolamos
