#include "align/stored_frames.h"

#include <filesystem>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "engine/preprocess.h"
#include "rolamos/error.hpp"
#include "engine/stage_options.h"

namespace rolamos {

FeatureOptions StoredFrameFeatureOptions() { return ToFeatureOptions(MosaickerOptions{}); }

std::string StoredFramePath(const std::string& source, const std::string& frames_dir) {
  if (frames_dir.empty()) return source;
  return (std::filesystem::path(frames_dir) / std::filesystem::path(source).filename()).string();
}

Features DescribeStoredFrame(const std::string& path, const FeatureExtractor& extractor) {
  const cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
  if (image.empty()) Fail(path, "cannot be read (is the frames' folder where the store says? it can be given as frames_dir)");
  static const Preprocessor pre{PreprocessOptions{}};  // CLAHE only: DetectionImage is const
  const double scale = extractor.options().ScaleFor(image.size());
  return extractor.ExtractScaled(pre.DetectionImage(image, scale), scale);
}

}  // namespace rolamos
