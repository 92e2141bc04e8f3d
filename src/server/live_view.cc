#include "server/live_view.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <opencv2/core.hpp>

#include "align/navigation_fit.h"
#include "rolamos/error.hpp"
#include "util/homography.h"

namespace rolamos {

namespace {

nlohmann::json Matrix(const cv::Matx33d& m) {
  const auto a = ToArray9(m);
  return nlohmann::json(std::vector<double>(a.begin(), a.end()));
}

cv::Matx33d ReadMatrix(const nlohmann::json& j) {
  std::array<double, 9> a{};
  for (size_t i = 0; i < 9; ++i) a[i] = j.at(i).get<double>();
  return ToMatx(a);
}

nlohmann::json Mapped(const cv::Matx33d& H, const cv::Point2d& p) {
  const cv::Point2d q = ApplyHomography(H, p);
  return {std::round(q.x * 100) / 100, std::round(q.y * 100) / 100};
}

}  // namespace

// The similarity from the view's world to the map that the frames' navigated centres give.
nlohmann::json FitLiveGeoref(const std::vector<std::pair<std::string, cv::Point2d>>& frames, cv::Size size,
                             const std::map<std::string, FrameNavigation>& nav) {
  std::vector<cv::Point2d> world, map;
  std::string crs;
  const double col = 0.5 * (size.width - 1), row = 0.5 * (size.height - 1);
  for (const auto& [source, centre] : frames) {
    const FrameNavigation* n = FindFrameNavigation(nav, source);
    if (!n || (!crs.empty() && n->crs != crs)) continue;
    crs = n->crs;
    const auto& g = n->geotransform;
    world.push_back(centre);
    map.emplace_back(g[0] + col * g[1] + row * g[2], g[3] + col * g[4] + row * g[5]);
  }
  if (world.size() < 2) return nullptr;
  const auto M = FitSimilarity(world, map);
  if (!M) return nullptr;
  std::vector<double> residuals;
  for (size_t i = 0; i < world.size(); ++i) {
    const cv::Point2d q = ApplyHomography(*M, world[i]);
    residuals.push_back(std::hypot(q.x - map[i].x, q.y - map[i].y));
  }
  std::sort(residuals.begin(), residuals.end());
  return {{"crs", crs},
          {"geotransform", {(*M)(0, 2), (*M)(0, 0), (*M)(0, 1), (*M)(1, 2), (*M)(1, 0), (*M)(1, 1)}},
          {"frames", world.size()},
          {"residual_median_m", residuals[residuals.size() / 2]},
          {"residual_max_m", residuals.back()}};
}

nlohmann::json LiveView(const Store& store, const nlohmann::json& preview, int max_patches,
                        const std::map<std::string, FrameNavigation>* nav) {
  nlohmann::json out = {{"patch", 0}, {"preview", nullptr}, {"patches", nlohmann::json::array()},
                        {"track", nlohmann::json::array()}, {"footprint", nlohmann::json::array()}};
  const int open = preview.value("patch", 0);
  if (open <= 0 || !preview.contains("image")) return out;
  out["patch"] = open;
  const cv::Matx33d image_to_world = ReadMatrix(preview.at("patch_to_image")).inv();
  out["preview"] = {{"image", preview.at("image")}, {"width", preview.at("width")},
                    {"height", preview.at("height")}, {"to_world", Matrix(image_to_world)}};
  out["footprint"] = preview.value("footprint", nlohmann::json::array());
  if (preview.contains("last_frame")) out["last_frame"] = preview["last_frame"];

  // Closed patches back along the chain, each placed through the links.
  std::vector<nlohmann::json> tracks;  // oldest patch's frames first, in the end
  std::vector<std::pair<std::string, cv::Point2d>> centres;  // every frame shown: name, world
  int id = preview.value("previous_patch", nlohmann::json(nullptr)).is_number() ? preview["previous_patch"].get<int>() : 0;
  // The open patch -> the previous patch's first frame, then -> its pixels through that frame's
  // placement in the written patch.
  cv::Matx33d world_from = cv::Matx33d::eye();  // previous patch's first-frame grid -> world
  if (id > 0) world_from = ReadMatrix(preview.at("to_previous_first")).inv();
  bool first = true;  // the first closed patch is reached through its first frame
  cv::Matx33d to_world;  // the current patch's pixels -> world
  std::set<int> seen;
  while (id > 0 && static_cast<int>(out["patches"].size()) < max_patches && !seen.count(id)) {
    seen.insert(id);
    PatchSidecar s;
    try {
      s = store.ReadSidecar(id);
    } catch (const Error&) {
      break;  // not yet written by the engine's writer
    }
    if (s.frames.empty()) break;
    if (first) {
      to_world = world_from * ToMatx(s.frames.front().frame_to_patch).inv();
      first = false;
    }
    nlohmann::json track = nlohmann::json::array();
    const double fw = s.frame_size ? (*s.frame_size)[0] : 0, fh = s.frame_size ? (*s.frame_size)[1] : 0;
    for (const auto& f : s.frames) {
      track.push_back(Mapped(to_world * ToMatx(f.frame_to_patch), {fw / 2, fh / 2}));
      centres.emplace_back(f.source, ApplyHomography(to_world * ToMatx(f.frame_to_patch), {0.5 * (fw - 1), 0.5 * (fh - 1)}));
    }
    tracks.push_back(std::move(track));
    out["patches"].push_back({{"patch", id}, {"name", "patch-" + std::to_string(id)}, {"width", s.size[0]},
                              {"height", s.size[1]}, {"to_world", Matrix(to_world)}});
    if (!s.link) break;
    // This patch's pixels -> the previous patch's pixels.
    to_world = to_world * ToMatx(s.link->to_previous).inv();
    id = s.link->previous_patch;
  }
  for (auto it = tracks.rbegin(); it != tracks.rend(); ++it)
    for (const auto& p : *it) out["track"].push_back(p);
  const auto& track = preview.value("track", nlohmann::json::array());
  for (const auto& p : track) out["track"].push_back(p);
  if (nav) {
    const auto names = preview.value("track_frames", nlohmann::json::array());
    for (size_t i = 0; i < names.size() && i < track.size(); ++i)
      centres.emplace_back(names[i].get<std::string>(), cv::Point2d(track[i][0].get<double>(), track[i][1].get<double>()));
    const auto size = preview.value("frame_size", nlohmann::json::array());
    if (size.size() == 2) out["georef"] = FitLiveGeoref(centres, cv::Size(size[0].get<int>(), size[1].get<int>()), *nav);
  }
  return out;
}

}  // namespace rolamos
