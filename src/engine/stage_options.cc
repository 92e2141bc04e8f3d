#include "engine/stage_options.h"

#include <algorithm>

namespace rolamos {

FeatureOptions ToFeatureOptions(const MosaickerOptions& o) {
  FeatureOptions f;
  f.type = o.features;
  f.max_features = o.max_features;
  f.detect_scale = o.detect_scale;
  f.detect_pixels = o.detect_pixels;
  f.double_first_octave = o.sift_upsample;
  f.ratio = o.ratio;
  f.cross_check = o.cross_check;
  return f;
}

FeatureOptions CoarseFeatureOptions(const MosaickerOptions& o) {
  FeatureOptions f = ToFeatureOptions(o);
  f.double_first_octave = false;
  return f;
}

FeatureOptions DenseFeatureOptions(const MosaickerOptions& o) {
  FeatureOptions f = ToFeatureOptions(o);
  f.max_features = 3 * f.max_features;
  return f;
}

FeatureOptions FollowedFeatureOptions(FeatureOptions f, const MosaickerOptions& o) {
  f.max_features = std::min(f.max_features, o.followed_max_features);
  return f;
}

EgomotionOptions ToEgomotionOptions(const MosaickerOptions& o) {
  EgomotionOptions e;
  e.epipolar_threshold_px = o.epipolar_threshold;
  e.homography_threshold_px = o.homography_threshold;
  e.min_inliers = o.min_inliers;
  e.min_few_inliers = std::min(e.min_few_inliers, o.min_inliers);  // --min-inliers 12 asks 12 of any
  e.use_fundamental = o.fundamental;
  return e;
}

PreprocessOptions ToPreprocessOptions(const MosaickerOptions& o) {
  PreprocessOptions p;
  p.calibration = o.calibration;
  p.fov_deg = o.fov_deg;
  p.bilateral = o.bilateral;
  p.temporal = o.temporal;
  p.clahe = o.clahe;
  return p;
}

EccOptions ToEccOptions(const MosaickerOptions& o) {
  EccOptions e;
  e.enabled = o.ecc;
  e.scale = o.ecc_scale;
  e.motion = o.ecc_motion;
  return e;
}

TrackerOptions ToTrackerOptions(const MosaickerOptions& o) {
  TrackerOptions t;
  t.track_pixels = o.track_pixels;
  t.codec_pixels = o.video_track_pixels;
  t.max_points = o.track_points;
  t.window = o.track_window;
  t.turn_deg = o.track_turn_deg;
  t.turn_search_deg = o.track_turn_search_deg;
  // "auto" is decided by the input before the engine; frames pushed to it count as images.
  t.halve_once = o.track_halve == "always";
  return t;
}

PatchAdjustmentOptions ToPatchAdjustmentOptions(const MosaickerOptions& o) {
  PatchAdjustmentOptions a;
  a.enabled = o.adjust_patches;
  a.robust_loss_px = o.patch_robust_loss_px;
  // ("auto" never reaches the engine: MosaicInput replaces it by the file it writes, or by none.)
  a.solver.refine_focal = o.estimate_focal && (o.calibration.empty() || !o.calibration_focal_measured);
  return a;
}

}  // namespace rolamos
