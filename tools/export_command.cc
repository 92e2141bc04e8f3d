#include <cstdio>
#include <filesystem>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/cog_export.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/store.hpp"
#include "util/memory.h"
#include "util/progress.h"

namespace rolamos::cli {

struct ExportSwitches {
  std::string input, output, region;
  int level = -1;
  double scale = 1.0;
  int patch = 0;
  bool cog = false;
  TiffSwitches tiff;
  int jpeg_quality = 92;
  bool quiet = false;
};

// A store exports its global mosaic, or one patch with --patch; a file exports itself.
static std::string ResolveSource(const ExportSwitches& s) {
  if (!Store::LooksLikeStore(s.input)) {
    if (s.patch > 0) Fail("--patch", s.input + " is not a store");
    return s.input;
  }
  Store store = Store::Open(s.input);
  // Without a mosaic, a store of one patch exports that patch.
  const auto patches = store.patches();
  if (s.patch == 0 && !store.HasMosaic() && patches.size() == 1) return store.ImagePath(patches[0].id);
  return store.ImagePath(s.patch);
}

static int RunExport(const ExportSwitches& s) {
  const std::string source_path = ResolveSource(s);
  Progress progress(s.cog ? "cog" : "export", s.quiet);
  auto on_progress = [&](double f) { progress.Update(f); };
  if (s.cog) {
    if (!s.region.empty() || s.level >= 0 || s.scale != 1.0)
      Fail("--cog", "exports the whole image at full resolution; export a region to .tif first");
    CogOptions c;
    c.compression = ToWriteOptions(s.tiff).compression;
    c.quality = s.tiff.quality;
    c.tile_size = s.tiff.tile == 256 ? 512 : s.tiff.tile;
    ExportCog(source_path, s.output, c, on_progress);
    progress.Done();
    std::printf("%s -> %s: Cloud Optimized GeoTIFF, %s, %.1f s\n", source_path.c_str(),
                s.output.c_str(), CompressionName(c.compression).c_str(),
                progress.ElapsedSeconds());
    return 0;
  }
  ExportOptions o;
  o.output = s.output;
  o.level = s.level;
  o.scale = s.scale;
  o.tiff = ToWriteOptions(s.tiff);
  o.jpeg_quality = s.jpeg_quality;
  if (!s.region.empty()) {
    auto r = ParseRegion(s.region);
    o.region = cv::Rect2d(r[0], r[1], r[2], r[3]);
  }
  TiledImage image = TiledImage::Open(source_path);
  ExportResult r = ExportRegion(image, o, on_progress);
  progress.Done();
  std::printf("%s -> %s: %lld x %lld (level %d, scale %.4g), %.1f s, peak memory %.0f MiB\n",
              source_path.c_str(), s.output.c_str(), r.width, r.height, r.level, r.scale,
              progress.ElapsedSeconds(), PeakRssMb());
  return 0;
}

void AddExportCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<ExportSwitches>();
  auto* cmd = app.add_subcommand(
      "export", "A region at full resolution or any scale (.tif streamed, .png, .jpg), or a COG");
  cmd->add_option("input", s->input, "a store (its mosaic, or --patch N) or an image file")
      ->required();
  cmd->add_option("-o,--output", s->output, "output file (.tif, .png, .jpg)")->required();
  cmd->add_option("--region", s->region, "x,y,w,h in full-resolution pixels (default: all)");
  auto* level = cmd->add_option("--level", s->level, "read this pyramid level as stored");
  cmd->add_option("--scale", s->scale, "output scale in (0, 1]")->excludes(level);
  cmd->add_option("--patch", s->patch, "export this patch of a store");
  cmd->add_flag("--cog", s->cog, "write a Cloud Optimized GeoTIFF with GDAL's COG driver");
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_option("--jpeg-quality", s->jpeg_quality, "quality of .jpg output")
      ->capture_default_str();
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunExport(*s); }; });
}

}  // namespace rolamos::cli
