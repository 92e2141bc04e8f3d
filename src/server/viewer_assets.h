// The viewer page (viewer/: HTML, script, style, and OpenSeadragon from viewer/node_modules),
// built into the binary so `rolamos serve` and `rolamos tiles` need no installed files.
#pragma once

#include <cstddef>
#include <vector>

namespace rolamos {

struct ViewerAsset {
  const char* path;  // URL path below the site root, e.g. "index.html"
  const char* mime;
  const unsigned char* data;
  size_t size;
};

const std::vector<ViewerAsset>& ViewerAssets();

}  // namespace rolamos
