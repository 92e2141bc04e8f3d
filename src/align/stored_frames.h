// Matching frames after the online run (loop closure, place recognition): the frames are read
// again from where the sidecars say (or from a folder they were moved to), described with the
// engine's own feature settings, and a match between two is kept only when a RANSAC homography
// verifies it.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "engine/features.h"

namespace rolamos {

// The feature settings `rolamos mosaic` uses by default (MosaickerOptions).
FeatureOptions StoredFrameFeatureOptions();

// `source` as recorded in a sidecar, or its file name in `frames_dir` when that is given.
std::string StoredFramePath(const std::string& source, const std::string& frames_dir);

// The frame's features; throws Error naming the file (and --frames) when it cannot be read.
Features DescribeStoredFrame(const std::string& path, const FeatureExtractor& extractor);

}  // namespace rolamos
