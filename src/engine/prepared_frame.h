// A frame between the two halves of the engine: what Mosaicker::Prepare made of it (on any
// thread) and what Mosaicker::Integrate takes, in order.
#pragma once

#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "engine/features.h"

namespace rolamos {

struct PreparedFrame {
  std::string source, error;
  cv::Size size;
  cv::Mat spatial, detect;
  Features features;
  // Matched in the prepare stage against the frame prepared just before (usually the one it
  // will be registered to); `matched_to` identifies those features so Integrate can tell.
  std::shared_ptr<const Features> own;
  std::shared_ptr<const Features> matched_to;
  Matches matches;
};

}  // namespace rolamos
