#include "rolamos/link_patches.hpp"

#include <chrono>
#include <filesystem>
#include <map>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "engine/features.h"
#include "engine/preprocess.h"
#include "rolamos/error.hpp"
#include "util/homography.h"

namespace rolamos {

bool LinkOptions::IsValid(std::string* error) const {
  if (probe_frames < 1 || min_inliers < 8) {
    *error = "at least one probe frame and 8 inliers are needed";
    return false;
  }
  return true;
}

LinkSummary LinkPatches(Store store, const LinkOptions& options, const std::function<void(double)>& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("link options", error);
  const auto start = std::chrono::steady_clock::now();
  LinkSummary summary;
  std::vector<PatchSidecar> patches;
  for (const auto& e : store.patches()) patches.push_back(store.ReadSidecar(e.id));
  FeatureOptions fo;
  fo.max_features = 1000;
  fo.detect_scale = 0.4;
  const FeatureExtractor extractor(fo);
  const Preprocessor pre(PreprocessOptions{});
  std::map<std::pair<int, size_t>, Features> described;  // (patch, frame record)
  auto describe = [&](const PatchSidecar& s, size_t k) -> const Features& {
    auto key = std::make_pair(s.id, k);
    auto it = described.find(key);
    if (it != described.end()) return it->second;
    std::string path = s.frames[k].source;
    if (!options.frames_dir.empty())
      path = (std::filesystem::path(options.frames_dir) / std::filesystem::path(path).filename()).string();
    const cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
    if (image.empty()) Fail(path, "cannot be read (give the frames' folder with --frames DIR)");
    ++summary.frames_described;
    return described[key] = extractor.Extract(pre.DetectionImage(image));
  };
  // Patches placed so far: the first, and every one linked (by the engine or here).
  std::vector<bool> placed(patches.size(), false);
  for (size_t i = 0; i < patches.size(); ++i) {
    const PatchSidecar& s = patches[i];
    if (i == 0 || s.patch_to_global || s.extra.contains("link")) {
      placed[i] = true;
      continue;
    }
    if (s.frames.empty()) {
      summary.unlinked.emplace_back(s.id, "has no frames");
      continue;
    }
    int best_inliers = 0, best_patch = -1;
    cv::Matx33d best_to_previous;
    std::string unreadable;
    try {
    for (size_t p = 0; p < s.frames.size() && p < static_cast<size_t>(options.probe_frames); ++p) {
      const Features& probe = describe(s, p);
      for (size_t j = 0; j < patches.size(); ++j) {
        if (j == i || !placed[j]) continue;
        const PatchSidecar& o = patches[j];
        for (size_t k = 0; k < o.frames.size(); ++k) {
          const Matches m = MatchFeatures(probe, describe(o, k), fo);
          if (static_cast<int>(m.from.size()) < options.min_inliers) continue;
          std::vector<uchar> inlier;
          const cv::Mat H = cv::findHomography(m.from, m.to, cv::RANSAC, 3.0, inlier, 2000, 0.999);
          int count = 0;
          for (uchar v : inlier) count += v;
          if (H.empty() || count <= best_inliers || count < options.min_inliers) continue;
          best_inliers = count;
          best_patch = o.id;
          // this patch's pixels -> probe frame -> matched frame -> that patch's pixels
          best_to_previous = ToMatx(o.frames[k].frame_to_patch) * cv::Matx33d(H) * ToMatx(s.frames[p].frame_to_patch).inv();
        }
      }
    }
    } catch (const Error& e) {
      unreadable = e.what();  // the frames are gone: nothing can be recognised, say so
    }
    if (progress) progress(double(i + 1) / patches.size());
    if (best_patch < 0) {
      summary.unlinked.emplace_back(s.id, unreadable.empty() ? "no frame of an earlier patch matches its first frames"
                                                             : "place recognition needs the frames: " + unreadable);
      continue;
    }
    PatchSidecar updated = s;
    updated.extra["link"] = {{"previous_patch", best_patch},
                             {"to_previous", ToArray9(best_to_previous)},
                             {"method", "place_recognition"},
                             {"inliers", best_inliers}};
    store.UpdateSidecar(updated);
    patches[i] = updated;
    placed[i] = true;
    summary.linked.emplace_back(s.id, best_patch);
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos
