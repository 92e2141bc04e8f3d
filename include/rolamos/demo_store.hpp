// The README's main job before a survey exists: a generated seafloor image written into a new
// store as one patch, streamed band by band (never whole in memory).
#pragma once

#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct DemoOptions {
  std::string store = "demo.rolamos";
  long long width = 16384;
  long long height = 16384;
  TiffWriteOptions tiff;
  bool IsValid(std::string* error) const;
};

struct DemoResult {
  int patch_id = 0;
  std::string image_path;
  TiffWriteStats stats;
};

DemoResult WriteDemoStore(const DemoOptions& options, const ProgressFn& progress = nullptr);

}  // namespace rolamos
