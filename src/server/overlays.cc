#include "server/overlays.h"

#include <filesystem>
#include <fstream>

#include <opencv2/core.hpp>

#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "util/homography.h"

namespace rolamos {

namespace {

nlohmann::json Quad(const cv::Matx33d& H, double w, double h) {
  nlohmann::json points = nlohmann::json::array();
  for (const cv::Point2d p : {cv::Point2d(0, 0), cv::Point2d(w, 0), cv::Point2d(w, h), cv::Point2d(0, h)}) {
    const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1);
    points.push_back({q[0] / q[2], q[1] / q[2]});
  }
  return points;
}


}  // namespace

nlohmann::json ImageOverlays(const Store& store, const std::string& name, const std::string& path) {
  nlohmann::json out = {{"name", name},
                        {"outlines", nlohmann::json::array()},
                        {"footprints", nlohmann::json::array()},
                        {"trajectory", nlohmann::json::array()},
                        {"detections", nlohmann::json::array()},
                        {"problems", nlohmann::json::array()},
                        {"georef", nullptr}};
  const bool mosaic = name == "mosaic";
  const int only = mosaic ? 0 : std::atoi(name.c_str() + 6);  // "patch-N"
  for (const auto& entry : store.patches()) {
    if (!mosaic && entry.id != only) continue;
    PatchSidecar s;
    try {
      s = store.ReadSidecar(entry.id);
    } catch (const Error& e) {
      out["problems"].push_back(e.what());
      continue;
    }
    cv::Matx33d to_image = cv::Matx33d::eye();
    if (mosaic) {
      if (!s.patch_to_global) {
        out["problems"].push_back("patch " + std::to_string(s.id) + " has no patch_to_global (not composed)");
        continue;
      }
      to_image = ToMatx(*s.patch_to_global);
    }
    out["outlines"].push_back({{"patch", s.id},
                               {"points", Quad(to_image, double(s.size[0]), double(s.size[1]))}});
    const double fw = s.frame_size ? (*s.frame_size)[0] : 0;
    const double fh = s.frame_size ? (*s.frame_size)[1] : 0;
    for (const auto& f : s.frames) {
      const cv::Matx33d H = to_image * ToMatx(f.frame_to_patch);
      const std::string source = std::filesystem::path(f.source).filename().string();
      if (fw > 0) {
        out["footprints"].push_back({{"patch", s.id}, {"frame", f.index}, {"source", source},
                                     {"points", Quad(H, fw, fh)}});
        // How sure the aligned map is of the frame (rolamos align): the viewer's confidence layer.
        if (f.uncertainty_px) out["footprints"].back()["uncertainty_px"] = *f.uncertainty_px;
        if (f.residual_px) out["footprints"].back()["residual_px"] = *f.residual_px;
        if (f.placement_doubtful.value_or(false)) out["footprints"].back()["doubtful"] = true;
      }
      const cv::Point2d c = ApplyHomography(H, {fw / 2, fh / 2});
      out["trajectory"].push_back({{"frame", f.index}, {"patch", s.id}, {"point", {c.x, c.y}}});
    }
  }
  // Detections made on this very image.
  const std::string detections = store.dir() + "/objects/detections.geojson";
  if (std::filesystem::exists(detections)) {
    try {
      std::ifstream in(detections);
      const nlohmann::json doc = nlohmann::json::parse(in);
      const std::string image = doc.at("rolamos").at("image").get<std::string>();
      if (std::filesystem::path(store.dir()) / image == std::filesystem::path(path))
        for (const auto& f : doc.at("features"))
          out["detections"].push_back({{"class", f.at("properties").at("class")},
                                       {"score", f.at("properties").at("score")},
                                       {"bbox", f.at("properties").at("pixel_bbox")}});
    } catch (const std::exception& e) {
      out["problems"].push_back(detections + ": " + e.what());
    }
  }
  // The density layer over the same image (rolamos objects detect).
  const std::string density = store.dir() + "/objects/density.geojson";
  if (std::filesystem::exists(density)) {
    try {
      std::ifstream in(density);
      const nlohmann::json doc = nlohmann::json::parse(in);
      if (std::filesystem::path(store.dir()) / doc.at("rolamos").at("image").get<std::string>() == std::filesystem::path(path)) {
        nlohmann::json cells = nlohmann::json::array();
        for (const auto& f : doc.at("features"))
          cells.push_back({{"bbox", f.at("properties").at("pixel_bbox")},
                           {"count", f.at("properties").at("count")},
                           {"density", f.at("properties").at("density")}});
        const bool metres = doc.at("rolamos").at("density_unit") == "per_m2";
        out["density"] = {{"unit", metres ? "per m²" : "per megapixel"}, {"cells", cells}};
      }
    } catch (const std::exception& e) {
      out["problems"].push_back(density + ": " + e.what());
    }
  }
  try {
    if (const auto g = ReadGeoref(path)) {
      const std::string code = CrsAuthorityCode(g->crs);
      out["georef"] = {{"crs", code.empty() ? "local" : code}, {"geotransform", g->geotransform}};
    }
  } catch (const Error& e) {
    out["problems"].push_back(e.what());
  }
  return out;
}

}  // namespace rolamos
