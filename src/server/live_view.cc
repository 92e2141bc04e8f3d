#include "server/live_view.h"

#include <set>

#include <opencv2/core.hpp>

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

nlohmann::json LiveView(const Store& store, const nlohmann::json& preview, int max_patches) {
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
    for (const auto& f : s.frames) track.push_back(Mapped(to_world * ToMatx(f.frame_to_patch), {fw / 2, fh / 2}));
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
  for (const auto& p : preview.value("track", nlohmann::json::array())) out["track"].push_back(p);
  return out;
}

}  // namespace rolamos
