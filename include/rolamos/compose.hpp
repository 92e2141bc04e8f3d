// The global mosaic: patches placed in one frame and composed out of core, band by band, into the
// store's mosaic.tif (pyramidal tiled BigTIFF). Placement in this version: a patch's own
// patch_to_global when its sidecar has one, otherwise the chain of links between consecutive
// patches written by the engine; a patch that neither places is left out and reported, not
// guessed. (Place recognition and global alignment are the next steps.)
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "rolamos/export.hpp"
#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct ComposeOptions {
  long long max_pixels = 0;  // 0: full resolution; otherwise the scale that fits this many pixels
  TiffWriteOptions tiff;     // the mosaic's codec and tiles
  double cache_mb = 256;     // tile cache for reading the patches
  int feather_px = 64;       // blend width across patch seams, in patch pixels

  bool IsValid(std::string* error) const;
};

struct ComposeResult {
  long long width = 0, height = 0;
  double scale = 1.0;
  int patches_used = 0;
  std::vector<std::pair<int, std::string>> left_out;  // patch id, why
};

ComposeResult ComposeMosaic(Store store, const ComposeOptions& options,
                            const ProgressFn& progress = nullptr);

}  // namespace rolamos
