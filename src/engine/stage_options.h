// The mosaic options, split into each stage's own options (so each stage validates its part).
#pragma once

#include "engine/ecc_refine.h"
#include "engine/egomotion.h"
#include "engine/features.h"
#include "engine/patch_adjustment.h"
#include "engine/preprocess.h"
#include "engine/tracker.h"
#include "rolamos/mosaicker.hpp"

namespace rolamos {

FeatureOptions ToFeatureOptions(const MosaickerOptions& o);
// The same without SIFT's doubled first octave: for keyframes that link but are not blended.
FeatureOptions CoarseFeatureOptions(const MosaickerOptions& o);
// Recovery's last try on frames that overlap little: three times max_features.
FeatureOptions DenseFeatureOptions(const MosaickerOptions& o);
// `f` for keyframes that frames were followed into (MosaickerOptions::followed_max_features).
FeatureOptions FollowedFeatureOptions(FeatureOptions f, const MosaickerOptions& o);
EgomotionOptions ToEgomotionOptions(const MosaickerOptions& o);
PreprocessOptions ToPreprocessOptions(const MosaickerOptions& o);
EccOptions ToEccOptions(const MosaickerOptions& o);
TrackerOptions ToTrackerOptions(const MosaickerOptions& o);
PatchAdjustmentOptions ToPatchAdjustmentOptions(const MosaickerOptions& o);

}  // namespace rolamos
