// What the viewer shows of a live run (/api/live): the open patch's preview (live/preview.json,
// written by the engine) with the patches it continues beneath it, all in one frame: the open
// patch's coordinates ("world"). A patch closed by the pixel budget links to the one before
// (`link.to_previous` in its sidecar), and the open patch to the last closed one
// (`to_previous_first`), so the chain is followed back until a patch that began after a break.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include <map>

#include "rolamos/georeference.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

// `preview`: live/preview.json as read (patch 0 when nothing is open). Returns
//   {"patch": id, "preview": {"image", "width", "height", "to_world"} | null,
//    "patches": [{"patch", "name", "width", "height", "to_world"}, ...] (newest first),
//    "track": [[x, y], ...], "footprint": [[x, y] x 4], "last_frame": {"index", "source"}}
// with 3 x 3 homographies (row-major) from image pixels to world coordinates. At most
// `max_patches` closed patches; a sidecar not yet written ends the chain.
// With `nav` (frames' navigation by name), also "georef": {"crs", "geotransform" (world -> map,
// GDAL order), "frames" (with navigation), "residual_median_m", "residual_max_m"}, fitted over
// the frames shown, once two of them have navigation.
nlohmann::json LiveView(const Store& store, const nlohmann::json& preview, int max_patches = 8,
                        const std::map<std::string, FrameNavigation>* nav = nullptr);

}  // namespace rolamos
