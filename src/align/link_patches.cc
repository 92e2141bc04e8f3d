#include "rolamos/link_patches.hpp"

#include <chrono>
#include <filesystem>
#include <map>
#include <set>


#include "align/stored_frames.h"
#include "engine/registration.h"
#include "rolamos/error.hpp"
#include "store/frame_data.h"
#include "store/writer_lock.h"
#include "util/homography.h"

namespace rolamos {

bool LinkOptions::IsValid(std::string* error) const {
  if (probe_frames < 1 || min_inliers < 8) {
    *error = "at least one probe frame and 8 inliers are needed";
    return false;
  }
  return true;
}

namespace {

struct Found {
  int inliers = 0;
  int patch = -1;  // none
  cv::Matx33d to_previous = cv::Matx33d::eye();
};

}  // namespace

LinkSummary LinkPatches(Store store, const LinkOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("link options", error);
  // Linking rewrites sidecars it read: refused while an engine, align or compose writes the store.
  const auto lock = LockStoreForChange(store, "rolamos link");
  const auto start = std::chrono::steady_clock::now();
  LinkSummary summary;
  std::vector<PatchSidecar> patches;
  for (const auto& e : store.patches()) patches.push_back(store.ReadSidecar(e.id));
  const FeatureOptions fo = StoredFrameFeatureOptions();
  const FeatureExtractor extractor(fo);
  std::map<std::pair<int, size_t>, Features> described;  // (patch, frame record)
  std::set<int> loaded;  // patches whose stored features are in `described`
  auto describe = [&](const PatchSidecar& s, size_t k) -> const Features& {
    auto key = std::make_pair(s.id, k);
    auto it = described.find(key);
    if (it != described.end()) return it->second;
    // The features the engine stored with the patch, when it did: no frame is read again.
    if (s.frame_features && loaded.insert(s.id).second) {
      std::map<int, size_t> record;
      for (size_t r = 0; r < s.frames.size(); ++r) record[s.frames[r].index] = r;
      for (const auto& f : ReadFrameFeatures((std::filesystem::path(store.dir()) / *s.frame_features).string())) {
        auto r = record.find(f.index);
        if (r == record.end()) continue;
        // Its primary features: as many as the patches' links were found with before, matched as
        // the stored bytes (the same matches as floats).
        const int n = std::min<int>(static_cast<int>(f.points.size()), kPrimaryStoredFeatures);
        Features g;
        g.points.assign(f.points.begin(), f.points.begin() + n);
        g.descriptors = f.descriptors.rowRange(0, n);
        described[{s.id, r->second}] = std::move(g);
      }
      it = described.find(key);
      if (it != described.end()) return it->second;
    }
    Features f = DescribeStoredFrame(StoredFramePath(s.frames[k].source, options.frames_dir), extractor);
    f.descriptors.convertTo(f.descriptors, CV_8U);  // as the stored ones: SIFT's whole numbers, exact
    ++summary.frames_described;
    return described[key] = std::move(f);
  };
  // Patches placed so far: the first, and every one linked (by the engine or here).
  std::vector<bool> placed(patches.size(), false);
  // The best verified match of patch i's first frames among the placed patches' frames.
  auto find_link = [&](size_t i) {
    const PatchSidecar& s = patches[i];
    Found best;
    for (size_t p = 0, probed = 0; p < s.frames.size() && probed < static_cast<size_t>(options.probe_frames); ++p) {
      if (!s.frames[p].is_described()) continue;  // only described keyframes have stored features
      ++probed;
      const Features& probe = describe(s, p);
      for (size_t j = 0; j < patches.size(); ++j) {
        if (j == i || !placed[j]) continue;
        const PatchSidecar& o = patches[j];
        for (size_t k = 0; k < o.frames.size(); ++k) {
          if (!o.frames[k].is_keyframe()) continue;
          const VerifiedMatch v = MatchVerified(probe, describe(o, k), fo, options.min_inliers);
          if (v.inliers <= best.inliers) continue;
          // this patch's pixels -> probe frame -> matched frame -> that patch's pixels
          best = {v.inliers, o.id, ToMatx(o.frames[k].frame_to_patch) * v.H * ToMatx(s.frames[p].frame_to_patch).inv()};
        }
      }
    }
    return best;
  };
  for (size_t i = 0; i < patches.size(); ++i) {
    const PatchSidecar& s = patches[i];
    if (i == 0 || s.patch_to_global || s.link) {
      placed[i] = true;
      continue;
    }
    if (s.frames.empty()) {
      summary.unlinked.emplace_back(s.id, "has no frames");
      continue;
    }
    Found best;
    std::string unreadable;
    try {
      best = find_link(i);
    } catch (const Error& e) {
      unreadable = e.what();  // the frames are gone: nothing can be recognised, say so
    }
    if (progress) progress(double(i + 1) / patches.size());
    if (best.patch < 0) {
      summary.unlinked.emplace_back(s.id, unreadable.empty() ? "no frame of an earlier patch matches its first frames"
                                                             : "place recognition needs the frames: " + unreadable);
      continue;
    }
    PatchSidecar updated = s;
    updated.link = PatchLink{best.patch, ToArray9(best.to_previous), "place_recognition", best.inliers};
    store.UpdateSidecar(updated);
    patches[i] = updated;
    placed[i] = true;
    summary.linked.emplace_back(s.id, best.patch);
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos
