// Frames against their navigation: the correspondences and the robust similarity fit that both
// georeferencing (GeoreferenceMosaic) and alignment with navigation (AlignStore) use.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/georeference.hpp"

namespace rolamos {

// A frame's navigation, looked up by "sequence/name" (the frame's folder and file name), then by
// its file name; nullptr when it has none.
const FrameNavigation* FindFrameNavigation(const std::map<std::string, FrameNavigation>& nav,
                                           const std::string& source);

// Five points near a frame's centre (where lens distortion matters least), appended as their
// place through `frame_to_global` and their place on the map by the frame's navigation.
void AddNavigationPoints(const FrameNavigation& nav, const cv::Matx33d& frame_to_global, cv::Size frame,
                         std::vector<cv::Point2d>* global, std::vector<cv::Point2d>* map);

// The similarity from `from` to `to` that most points agree with (least median of squares),
// fitted about the means because map coordinates are large numbers; none if nothing fits.
std::optional<cv::Matx33d> FitSimilarity(const std::vector<cv::Point2d>& from, const std::vector<cv::Point2d>& to);

}  // namespace rolamos
