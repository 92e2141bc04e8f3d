#include "engine/ecc_refine.h"

#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "engine/area_resize.h"
#include "engine/ecc_translation.h"
#include "engine/patch_canvas.h"

namespace rolamos {

bool EccOptions::IsValid(std::string* error) const {
  if (motion != "translation" && motion != "euclidean" && motion != "affine" && motion != "homography") {
    *error = "ECC motion \"" + motion + "\" is not translation, euclidean, affine or homography";
    return false;
  }
  if (!(scale > 0.02 && scale <= 1.0) || levels < 1 || levels > 5 || iterations < 1 ||
      !(min_correlation >= 0 && min_correlation < 1) || !(max_shift_px > 0)) {
    *error = "ECC settings are out of range (scale (0.02,1], levels 1..5, iterations >= 1)";
    return false;
  }
  return true;
}

namespace {

// Maps pixel coordinates between a full-resolution frame and its version at `s`.
cv::Matx33d ScaleMap(double s) {  // full -> scaled
  return cv::Matx33d(s, 0, 0.5 * (s - 1), 0, s, 0.5 * (s - 1), 0, 0, 1);
}

// Removes shading (vignetting, light falloff, haze gradients) that differs between a frame and
// the blended mosaic: ECC is invariant to one gain and offset, not to gain that varies across the
// frame, and would turn the difference into a false scale change. Normalised convolution keeps
// the empty outside of the mosaic out of the local mean.
cv::Mat HighPass(const cv::Mat& gray, const cv::Mat& mask, double sigma) {
  cv::Mat f, m, blurred, weight;
  gray.convertTo(f, CV_32F);
  mask.convertTo(m, CV_32F, 1.0 / 255.0);
  // The local mean is smooth: compute it at a quarter of the resolution (a wide Gaussian at
  // full size would cost more than the ECC iterations).
  auto smooth = [&](const cv::Mat& in, cv::Mat& out) {
    cv::Mat small;
    cv::resize(in, small, cv::Size(), 0.25, 0.25, cv::INTER_AREA);
    cv::GaussianBlur(small, small, cv::Size(), sigma / 4);
    cv::resize(small, out, in.size(), 0, 0, cv::INTER_LINEAR);
  };
  smooth(f.mul(m), blurred);
  smooth(m, weight);
  cv::Mat local_mean = blurred / cv::max(weight, 1e-3);
  cv::Mat out = (f - local_mean).mul(m);
  return out;
}

}  // namespace

EccResult RefineWithEcc(const cv::Mat& frame_gray, const cv::Matx33d& frame_to_patch,
                        const PatchCanvas& canvas, const EccOptions& o, const cv::Mat& frame_mask) {
  EccResult r;
  r.frame_to_patch = frame_to_patch;
  if (!o.enabled || canvas.empty()) return r;
  // W maps template (frame) pixels to input (mosaic seen from the frame) pixels at a level.
  const int motion = o.motion == "translation" ? cv::MOTION_TRANSLATION
                     : o.motion == "euclidean"   ? cv::MOTION_EUCLIDEAN
                     : o.motion == "affine"      ? cv::MOTION_AFFINE
                                                 : cv::MOTION_HOMOGRAPHY;
  cv::Mat W = cv::Mat::eye(motion == cv::MOTION_HOMOGRAPHY ? 3 : 2, 3, CV_32F);
  double correlation = 0;
  for (int level = o.levels - 1; level >= 0; --level) {
    const double s = o.scale / std::pow(2.0, level);
    cv::Mat templ, input, mask;
    ResizeArea(frame_gray, templ, s);
    canvas.ViewFromFrame(frame_to_patch, frame_gray.size(), s, &input, &mask);
    cv::resize(input, input, templ.size());
    cv::resize(mask, mask, templ.size(), 0, 0, cv::INTER_NEAREST);
    // ECC smooths both images: keep away from the edge of the mosaic, where the smoothing
    // would mix in the empty outside and pull the estimate.
    cv::erode(mask, mask, cv::Mat(), cv::Point(-1, -1), 3);
    const double sigma = std::max(4.0, 0.04 * templ.cols);
    cv::Mat full(templ.size(), CV_8U, cv::Scalar(255));
    cv::Mat templ_hp = HighPass(templ, full, sigma), input_hp = HighPass(input, mask, sigma);
    if (!frame_mask.empty()) {  // overlays fixed in the frame: flat, they pull nothing
      cv::Mat usable;
      ResizeArea(frame_mask, usable, templ.size());
      cv::erode(usable, usable, cv::Mat(), cv::Point(-1, -1), 2);
      usable.convertTo(usable, CV_32F, 1.0 / 255);
      templ_hp = templ_hp.mul(usable);
    }
    if (cv::countNonZero(mask) < static_cast<int>(mask.total() / 10)) return r;  // little overlap
    if (level < o.levels - 1) {  // carry the coarser estimate to this level
      W.at<float>(0, 2) *= 2;
      W.at<float>(1, 2) *= 2;
      if (W.rows == 3) {
        W.at<float>(2, 0) /= 2;
        W.at<float>(2, 1) /= 2;
      }
    }
    // The engine's motion: ours (the stage took 7 ms a 1292 x 964 keyframe with OpenCV's, 2 with it).
    if (motion == cv::MOTION_TRANSLATION) {
      const EccTranslation t = FindEccTranslation(templ_hp, input_hp, mask,
                                                  {W.at<float>(0, 2), W.at<float>(1, 2)}, o.iterations, o.epsilon);
      if (!t.ok) return r;  // did not converge: keep the feature estimate
      W.at<float>(0, 2) = static_cast<float>(t.shift.x);
      W.at<float>(1, 2) = static_cast<float>(t.shift.y);
      correlation = t.correlation;
      continue;
    }
    try {
      correlation = cv::findTransformECC(
          templ_hp, input_hp, W, motion,
          cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, o.iterations, o.epsilon),
          mask, 3);
    } catch (const cv::Exception&) {
      return r;  // did not converge: keep the feature estimate
    }
  }
  r.correlation = correlation;
  if (correlation < o.min_correlation) return r;
  // Back to full resolution: correction C = S^-1 W S maps frame pixels to frame pixels.
  const cv::Matx33d S = ScaleMap(o.scale);
  cv::Mat W3 = cv::Mat::eye(3, 3, CV_64F);
  W.convertTo(W3.rowRange(0, W.rows), CV_64F);
  const cv::Matx33d C = S.inv() * cv::Matx33d(W3) * S;
  // Refuse large corrections: ECC found another optimum, not a refinement.
  const cv::Point2d corners[] = {{0, 0},
                                 {frame_gray.cols - 1.0, 0},
                                 {0, frame_gray.rows - 1.0},
                                 {frame_gray.cols - 1.0, frame_gray.rows - 1.0}};
  for (const auto& p : corners) {
    cv::Vec3d q = C * cv::Vec3d(p.x, p.y, 1);
    if (std::hypot(q[0] / q[2] - p.x, q[1] / q[2] - p.y) > o.max_shift_px) return r;
  }
  r.frame_to_patch = frame_to_patch * C;
  r.applied = true;
  return r;
}

}  // namespace rolamos
