// Place recognition for patches that lost the thread: a patch that starts after tracking was
// lost has no link to the patches before it. Its first frames are matched against every frame of
// the earlier patches (SIFT, ratio and mutual checks, RANSAC homography); the best verified match
// becomes its link ("link": {"previous_patch", "to_previous", "method": "place_recognition",
// "inliers"}). A patch nothing verifies stays unlinked and is reported, not guessed.
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct LinkOptions {
  std::string frames_dir;   // where the frames are, when not where the sidecars say
  int probe_frames = 3;     // first frames of an unlinked patch that are tried
  int min_inliers = 40;     // homography inliers a link needs

  bool IsValid(std::string* error) const;
};

struct LinkSummary {
  std::vector<std::pair<int, int>> linked;                // (patch, to patch)
  std::vector<std::pair<int, std::string>> unlinked;      // (patch, why)
  int frames_described = 0;
  double seconds = 0;
};

LinkSummary LinkPatches(Store store, const LinkOptions& options,
                        const ProgressFn& progress = {});

}  // namespace rolamos
