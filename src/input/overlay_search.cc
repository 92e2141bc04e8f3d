#include "input/overlay_search.h"

#include <algorithm>

#include <opencv2/imgproc.hpp>

#include "engine/preprocess.h"
#include "engine/stage_options.h"
#include "input/frame_source.h"
#include "rolamos/error.hpp"

namespace rolamos {

namespace {

// `image` as the engine will see it; empty when the calibration does not fit it (the engine's to
// report).
cv::Mat AsTheEngineSees(Preprocessor& pre, const cv::Mat& image) {
  try {
    return pre.Undistort(image);
  } catch (const Error&) {
    return {};
  }
}

}  // namespace

StaticMask FindOverlay(const std::vector<cv::Mat>& raw, const MosaickerOptions& options) {
  Preprocessor pre(ToPreprocessOptions(options));
  std::vector<cv::Mat> frames;
  for (const cv::Mat& image : raw) {
    if (image.empty()) continue;
    if (cv::Mat seen = AsTheEngineSees(pre, image); !seen.empty()) frames.push_back(seen);
  }
  return EstimateStaticMask(frames, StaticMaskOptions());
}

OverlayWindows::OverlayWindows(const MosaickerOptions& options, int skip, const OverlaySearchOptions& search)
    : search_(search), skip_(skip), pre_(ToPreprocessOptions(options)) {
  result_.conclusive = false;
  result_.note = "no frames after the first " + std::to_string(skip);
}

bool OverlayWindows::Add(int index, const cv::Mat& image) {
  ++seen_;
  if (image.empty()) return false;
  if (!latest_.empty() && image.size() != latest_.back().second.size()) latest_.clear();  // another camera size
  cv::Mat grey;
  if (image.channels() == 1) grey = image;
  else cv::cvtColor(image, grey, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  grey = AsTheEngineSees(pre_, grey);
  if (grey.empty()) return false;
  latest_.emplace_back(index, grey);
  const int window = mask_options_.frames;
  if (static_cast<int>(latest_.size()) > window) latest_.pop_front();
  if (static_cast<int>(latest_.size()) < window || ++since_ < search_.step) return false;
  since_ = 0;
  std::vector<cv::Mat> frames;
  for (const auto& [i, g] : latest_) frames.push_back(g);
  result_ = EstimateStaticMask(frames, mask_options_);
  result_.note += " in frames " + std::to_string(latest_.front().first) + "-" + std::to_string(latest_.back().first) +
                  " (the first " + std::to_string(skip_) + " could not tell)";
  return true;
}

std::string OverlayWindows::FinalNote(int read) const {
  return result_.note + "; searched " + std::to_string(read < 0 ? seen_ : read) + " frames";
}

StaticMask SearchOverlayFurther(const std::string& input, int skip, const MosaickerOptions& options,
                                const OverlaySearchOptions& search, const std::atomic<bool>* stop) {
  const auto source = FrameSource::Open(input);
  OverlayWindows windows(options, skip, search);
  InputFrame f;
  int read = 0;
  while (read < search.max_frames && !(stop && stop->load()) && source->Next(&f)) {
    ++read;
    if (search.progress && read % std::max(1, search.progress_every) == 0) search.progress(read);
    if (f.index < skip) continue;
    if (windows.Add(f.index, f.image) && windows.conclusive()) return windows.result();
  }
  StaticMask result = windows.result();
  result.note = windows.FinalNote(read);
  return result;
}

}  // namespace rolamos
