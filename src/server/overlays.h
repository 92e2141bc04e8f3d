// What the viewer draws over an image of the store, in that image's level-0 pixels: patch
// outlines, frame footprints and the trajectory of frame centres (from the sidecars, through
// frame_to_patch and, on the global mosaic, patch_to_global), the object detections of
// `rolamos objects detect` made on that image, and the georeference for map coordinates.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "rolamos/store.hpp"

namespace rolamos {

// `name` as in StoreImages ("mosaic", "patch-N"); `path` its file. Sidecars that cannot be
// read are listed under "problems" rather than failing the whole overlay.
nlohmann::json ImageOverlays(const Store& store, const std::string& name, const std::string& path);

}  // namespace rolamos
