#include "input/overlay_search.h"

#include <deque>

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

StaticMask SearchOverlayFurther(const std::string& input, int skip, const MosaickerOptions& options,
                                const OverlaySearchOptions& search, const std::atomic<bool>* stop) {
  const StaticMaskOptions mo;
  const int window = mo.frames;
  const auto source = FrameSource::Open(input);
  // One preprocessor for the whole search (its undistortion maps are made once), and each frame
  // undistorted once, as it enters the window, not again in each of the three windows it is in.
  Preprocessor pre(ToPreprocessOptions(options));
  // The latest frames, grey (the search looks at nothing else; a third of the memory).
  std::deque<std::pair<int, cv::Mat>> latest;
  StaticMask result;
  result.conclusive = false;
  result.note = "no frames after the first " + std::to_string(skip);
  InputFrame f;
  int read = 0, since = 0;
  while (read < search.max_frames && !(stop && stop->load()) && source->Next(&f)) {
    ++read;
    if (f.index < skip || f.image.empty()) continue;
    if (!latest.empty() && f.image.size() != latest.back().second.size()) latest.clear();  // another camera size
    cv::Mat grey;
    if (f.image.channels() == 1) grey = f.image;
    else cv::cvtColor(f.image, grey, f.image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
    grey = AsTheEngineSees(pre, grey);
    if (grey.empty()) continue;
    latest.emplace_back(f.index, grey);
    if (static_cast<int>(latest.size()) > window) latest.pop_front();
    if (static_cast<int>(latest.size()) < window || ++since < search.step) continue;
    since = 0;
    std::vector<cv::Mat> frames;
    for (const auto& [index, image] : latest) frames.push_back(image);
    result = EstimateStaticMask(frames, mo);
    result.note += " in frames " + std::to_string(latest.front().first) + "-" + std::to_string(latest.back().first) +
                   " (the first " + std::to_string(skip) + " could not tell)";
    if (result.conclusive) return result;
  }
  result.note += "; searched " + std::to_string(read) + " frames";
  return result;
}

}  // namespace rolamos
