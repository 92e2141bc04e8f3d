#include "rolamos/demo_store.hpp"

#include "rolamos/error.hpp"
#include "rolamos/store.hpp"
#include "synth/seafloor_texture.h"

namespace rolamos {

bool DemoOptions::IsValid(std::string* error) const {
  PixelLayout layout;
  layout.width = width;
  layout.height = height;
  layout.channels = 3;
  if (width < 16 || height < 16 || width > 1000000 || height > 1000000) {
    *error = "demo size " + std::to_string(width) + " is outside 16..1000000";
    return false;
  }
  return tiff.IsValid(layout, error);
}

DemoResult WriteDemoStore(const DemoOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("demo", error);
  Store store = Store::Create(options.store);
  DemoResult result;
  result.patch_id = store.NextPatchId();
  result.image_path = store.PatchImagePath(result.patch_id);
  PixelLayout layout;
  layout.width = options.width;
  layout.height = options.height;
  layout.channels = 3;
  PyramidTiffWriter writer(result.image_path, layout, options.tiff);
  for (long long y = 0; y < options.height; y += writer.band_height()) {
    const int rows = static_cast<int>(std::min<long long>(writer.band_height(), options.height - y));
    writer.WriteBand(RenderSeafloor(0, y, static_cast<int>(options.width), rows));
    if (progress) progress(double(y + rows) / options.height);
  }
  result.stats = writer.Finish();

  PatchSidecar sidecar;
  sidecar.id = result.patch_id;
  sidecar.size = {options.width, options.height};
  sidecar.patch_to_global = IdentityHomography();
  sidecar.extra["generated"] = "procedural seafloor texture (rolamos demo)";
  store.CommitPatch(sidecar);
  GlobalRecord global = store.global();
  global.size = {options.width, options.height};
  store.SetGlobal(global);
  return result;
}

}  // namespace rolamos
