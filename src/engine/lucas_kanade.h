// Pyramidal Lucas-Kanade (Bouguet's formulation), the kernel under the tracker (tracker.h).
//
// The arithmetic is OpenCV's calcOpticalFlowPyrLK's: bilinear weights in 14 bits, intensities
// scaled by 32, Scharr derivatives from cv::buildOpticalFlowPyramid, the same stopping rules
// (a step under the criteria's epsilon, or a step that undoes the last one). What differs is
// how a window row is taken: 16 pixels at a time with AVX2, where OpenCV 4.6 takes 8 with
// 128-bit vectors and leaves the last 5 of a 21-pixel row to scalar code. Sums are added in
// another order, so results agree with OpenCV's to float rounding, not bit for bit
// (lucas_kanade_test.cc). Without AVX2 the call goes to OpenCV.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// `from` and `to` are pyramids from cv::buildOpticalFlowPyramid(..., withDerivatives = true)
// built with `window` (their borders must be at least a window wide). `found` holds each
// point's starting place in `to` on entry (OPTFLOW_USE_INITIAL_FLOW) and where it was followed
// to on return; `status` is 1 where the point was followed at every level. Only `from`'s
// derivatives are read.
void FollowLucasKanade(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                       const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                       std::vector<uchar>* status, cv::Size window, int levels, const cv::TermCriteria& until,
                       double min_eigen);

// Whether FollowLucasKanade runs its own vectorised kernel on this CPU (else OpenCV's).
bool LucasKanadeVectorised();

namespace detail {
// The kernel's scalar form (every window row as OpenCV's scalar tail computes it), for tests:
// the vectorised rows must give what these give.
void FollowLucasKanadeScalar(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                             const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                             std::vector<uchar>* status, cv::Size window, int levels,
                             const cv::TermCriteria& until, double min_eigen);
}  // namespace detail

}  // namespace rolamos
