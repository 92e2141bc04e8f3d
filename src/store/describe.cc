#include "rolamos/describe.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>

#include "rolamos/error.hpp"
#include "rolamos/store.hpp"
#include "rolamos/tiled_image.hpp"

namespace rolamos {

using json = nlohmann::json;

json DescribeImage(const std::string& path) {
  TiledImage image = TiledImage::Open(path);
  const auto& info = image.info();
  json j;
  j["kind"] = "image";
  j["path"] = path;
  j["format"] = info.format;
  std::error_code ec;
  j["file_bytes"] = std::filesystem::file_size(path, ec);
  j["bigtiff"] = info.bigtiff;
  j["channels"] = info.channels;
  j["bits"] = info.bits;
  j["alpha"] = info.has_alpha;
  j["compression"] = info.compression;
  json levels = json::array();
  for (const auto& l : info.levels) {
    json lj{{"width", l.width}, {"height", l.height}};
    if (l.tile_width > 0) {
      lj["tile"] = {l.tile_width, l.tile_height};
      lj["tiles"] = ((l.width + l.tile_width - 1) / l.tile_width) *
                    ((l.height + l.tile_height - 1) / l.tile_height);
    }
    levels.push_back(lj);
  }
  j["levels"] = levels;
  if (info.georef) {
    j["crs"] = info.georef->crs;
    j["geotransform"] = info.georef->geotransform;
  }
  return j;
}

json DescribeStore(const std::string& dir) {
  Store store = Store::Open(dir);
  json j;
  j["kind"] = "store";
  j["path"] = dir;
  j["format"] = kStoreFormat;
  j["version"] = kStoreVersion;
  j["global"] = GlobalToJson(store.global());
  j["camera"] = store.camera();
  json patches = json::array();
  for (const auto& p : store.patches()) {
    json pj{{"id", p.id}, {"image", p.image}, {"sidecar", p.sidecar}};
    try {
      PatchSidecar s = store.ReadSidecar(p.id);
      pj["size"] = s.size;
      pj["n_images"] = s.n_images;
      pj["rejected"] = s.rejected.size();
      pj["linked"] = s.patch_to_global.has_value();
      if (s.component) pj["component"] = *s.component;
      // How sure the aligned map is of this patch's frames (rolamos align's uncertainty_px).
      double worst = -1, sum = 0;
      int first = 0, last = 0, counted = 0, doubtful = 0;
      for (const auto& f : s.frames) {
        if (!f.uncertainty_px) continue;
        sum += *f.uncertainty_px;
        ++counted;
        doubtful += f.placement_doubtful.value_or(false);
        if (*f.uncertainty_px > worst) worst = *f.uncertainty_px, first = last = f.index;
        else if (*f.uncertainty_px == worst) last = std::max(last, f.index);
      }
      if (counted > 0)
        pj["confidence"] = {{"mean_uncertainty_px", sum / counted}, {"worst_uncertainty_px", worst},
                            {"worst_frame", first}, {"doubtful_frames", doubtful}};
      if (s.closed_by) pj["closed_by"] = *s.closed_by;
      json img = DescribeImage((std::filesystem::path(dir) / p.image).string());
      pj["levels"] = img["levels"].size();
      pj["compression"] = img["compression"];
      pj["file_bytes"] = img["file_bytes"];
      if (img["levels"][0]["width"] != s.size[0] || img["levels"][0]["height"] != s.size[1])
        pj["problem"] = "sidecar size disagrees with the image";
    } catch (const Error& e) {
      pj["problem"] = e.what();
    }
    patches.push_back(pj);
  }
  j["patches"] = patches;
  if (store.HasMosaic()) {
    try {
      j["mosaic"] = DescribeImage(store.MosaicPath());
    } catch (const Error& e) {
      j["mosaic"] = {{"problem", e.what()}};
    }
  }
  return j;
}

namespace {

std::string Fmt(const char* f, double a) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, a);
  return buf;
}

void FormatImage(const json& j, const std::string& indent, std::ostringstream& out) {
  out << indent << j["path"].get<std::string>() << ": " << j["format"].get<std::string>()
      << (j["bigtiff"].get<bool>() ? " (BigTIFF)" : "") << ", " << j["channels"] << " channel"
      << (j["channels"] == 1 ? "" : "s") << (j["alpha"].get<bool>() ? " with alpha" : "") << ", "
      << j["bits"] << "-bit, " << j["compression"].get<std::string>() << ", "
      << Fmt("%.1f MiB", j["file_bytes"].get<double>() / 1048576.0) << "\n";
  int k = 0;
  for (const auto& l : j["levels"]) {
    out << indent << "  level " << k++ << ": " << l["width"] << " x " << l["height"];
    if (l.contains("tile"))
      out << ", " << l["tiles"] << " tiles of " << l["tile"][0] << "x" << l["tile"][1];
    out << "\n";
  }
  if (j.contains("crs")) {
    const auto& gt = j["geotransform"];
    std::string crs = j["crs"].get<std::string>();
    const auto name_end = crs.find('"', crs.find('"') + 1);
    out << indent << "  georeferenced: "
        << (name_end != std::string::npos ? crs.substr(crs.find('"') + 1, name_end - crs.find('"') - 1) : crs.substr(0, 60))
        << ", origin " << Fmt("%.3f", gt[0].get<double>()) << ", "
        << Fmt("%.3f", gt[3].get<double>()) << ", pixel " << Fmt("%.4g", gt[1].get<double>())
        << " x " << Fmt("%.4g", gt[5].get<double>()) << "\n";
  } else {
    out << indent << "  not georeferenced\n";
  }
}

}  // namespace

std::string FormatDescription(const json& j) {
  std::ostringstream out;
  if (j["kind"] == "image") {
    FormatImage(j, "", out);
    return out.str();
  }
  const auto& g = j["global"];
  out << j["path"].get<std::string>() << ": rolamos store, format version " << j["version"]
      << "\n  global: " << g["size"][0] << " x " << g["size"][1] << " px, " << g["n_images"]
      << " images in " << g["n_patches"] << " patches, scale " << g["scale"]
      << (g["crs"].is_null() ? ", not georeferenced" : ", georeferenced") << "\n";
  // The parts of the map (after `rolamos align`): ground no frame connects lies between them.
  std::map<int, std::pair<int, int>> parts;  // component -> (patches, images)
  int unaligned = 0, rejected = 0;
  for (const auto& p : j["patches"]) {
    if (p.contains("rejected")) rejected += p["rejected"].get<int>();
    if (!p.contains("component")) {
      ++unaligned;
      continue;
    }
    auto& part = parts[p["component"].get<int>()];
    ++part.first;
    part.second += p.value("n_images", 0);
  }
  if (!parts.empty()) {
    out << "  map: " << parts.size() << (parts.size() == 1 ? " part:" : " parts (side by side where no ground connects them):");
    for (const auto& [c, pi] : parts) out << " [" << c << "] " << pi.second << " images in " << pi.first << " patches;";
    out << "\n";
  }
  if (unaligned && !parts.empty()) out << "  " << unaligned << " patches not in the aligned map (added after `rolamos align`?)\n";
  if (rejected) out << "  " << rejected << " frames rejected by the engine, each with its reason in its patch's sidecar\n";
  // Where the aligned map is least sure: the patches whose frames' uncertainty is highest.
  std::vector<std::pair<double, const json*>> unsure;
  for (const auto& p : j["patches"])
    if (p.contains("confidence")) unsure.emplace_back(p["confidence"]["worst_uncertainty_px"].get<double>(), &p);
  if (!unsure.empty()) {
    std::sort(unsure.begin(), unsure.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    out << "  least sure (uncertainty_px after align):";
    for (size_t k = 0; k < unsure.size() && k < 3; ++k) {
      const json& c = (*unsure[k].second)["confidence"];
      out << " patch " << (*unsure[k].second)["id"] << " up to " << Fmt("%.2f", unsure[k].first) << " px (frame "
          << c["worst_frame"] << (c["doubtful_frames"].get<int>() ? ", " + std::to_string(c["doubtful_frames"].get<int>()) +
                                                                        " doubtful" : "")
          << ");";
    }
    out << "\n";
  }
  for (const auto& p : j["patches"]) {
    out << "  patch " << p["id"] << ": ";
    if (p.contains("size"))
      out << p["size"][0] << " x " << p["size"][1] << ", " << p["n_images"] << " images, "
          << p["rejected"] << " rejected";
    if (p.contains("levels"))
      out << ", " << p["levels"] << " levels, " << p["compression"].get<std::string>() << ", "
          << Fmt("%.1f MiB", p["file_bytes"].get<double>() / 1048576.0);
    if (p.contains("component")) out << ", part " << p["component"];
    if (p.contains("closed_by")) out << ", closed by " << p["closed_by"].get<std::string>();
    if (p.contains("problem")) out << "  PROBLEM: " << p["problem"].get<std::string>();
    out << "\n";
  }
  if (j.contains("mosaic")) {
    out << "  mosaic:\n";
    if (j["mosaic"].contains("problem"))
      out << "    PROBLEM: " << j["mosaic"]["problem"].get<std::string>() << "\n";
    else
      FormatImage(j["mosaic"], "    ", out);
  } else {
    out << "  no global mosaic (mosaic.tif) yet\n";
  }
  return out.str();
}

}  // namespace rolamos
