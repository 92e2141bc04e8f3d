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

#include <memory>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// `from` and `to` are pyramids from cv::buildOpticalFlowPyramid(..., withDerivatives = true)
// built with `window` (their borders must be at least a window wide). `found` holds each
// point's starting place in `to` on entry (OPTFLOW_USE_INITIAL_FLOW) and where it was followed
// to on return; `status` is 1 where the point was followed at every level. Only `from`'s
// derivatives are read. `only` (optional): the indices of the points to follow; the others'
// `found` and `status` are left as they are. Each point is followed on its own: following some,
// then the rest, gives what following all at once does.
void FollowLucasKanade(const std::vector<cv::Mat>& from, const std::vector<cv::Mat>& to,
                       const std::vector<cv::Point2f>& points, std::vector<cv::Point2f>* found,
                       std::vector<uchar>* status, cv::Size window, int levels, const cv::TermCriteria& until,
                       double min_eigen, const std::vector<int>* only = nullptr);

// The windows of fixed points in a first image at every level (its intensities and derivatives
// interpolated, their second-moment matrix), made once and read by every follow from those points:
// frames are followed from the same keyframe points until the next keyframe, so this is half
// of the kernel's work done once per keyframe instead of once per frame.
class LucasKanadeTemplates;
std::shared_ptr<const LucasKanadeTemplates> PrepareLucasKanade(const std::vector<cv::Mat>& from,
                                                               const std::vector<cv::Point2f>& points,
                                                               cv::Size window, int levels, double min_eigen);
// As above, from windows made by PrepareLucasKanade (for `points`, with the same window, levels and
// smallest eigenvalue; `from` is the pyramid they were made from). `only` as above.
void FollowLucasKanade(const LucasKanadeTemplates& windows, const std::vector<cv::Mat>& from,
                       const std::vector<cv::Mat>& to, const std::vector<cv::Point2f>& points,
                       std::vector<cv::Point2f>* found, std::vector<uchar>* status, const cv::TermCriteria& until,
                       const std::vector<int>* only = nullptr);

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
