#include <cstdio>
#include <filesystem>
#include <optional>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/cog_export.hpp"
#include "rolamos/stac_export.hpp"
#include "rolamos/region_export.hpp"
#include "rolamos/store.hpp"
#include "store/writer_lock.h"
#include "util/memory.h"
#include "util/progress.h"

namespace rolamos::cli {

namespace fs = std::filesystem;

struct ExportSwitches {
  std::string input, output, region;
  int level = -1;
  double scale = 1.0;
  int patch = 0;
  bool cog = false;
  std::string stac;  // a catalogue directory
  StacOptions stac_options;
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

// The COG's path relative to the store when it lands inside it ("" otherwise): recorded in the
// manifest, so that `rolamos serve` hands it out (/files/...).
static std::string InsideStore(const std::string& store, const std::string& file) {
  const fs::path root = fs::weakly_canonical(store), out = fs::weakly_canonical(file);
  const fs::path rel = out.lexically_relative(root);
  if (rel.empty() || rel.native()[0] == '.') return "";
  return rel.string();
}

static int RunStac(const ExportSwitches& s) {
  if (!Store::LooksLikeStore(s.input)) Fail("--stac", s.input + " is not a store");
  Progress progress("stac", s.quiet);
  const StacResult r = ExportStac(Store::Open(s.input), s.stac, s.stac_options, [&](double f) { progress.Update(f); });
  progress.Done();
  std::printf("%s -> %s: STAC item (COG, thumbnail, footprint of %d part%s, time from %s) in %s, %.1f s\n",
              s.input.c_str(), r.item.c_str(), r.footprint_parts, r.footprint_parts == 1 ? "" : "s",
              r.time_source.c_str(), r.catalog.c_str(), progress.ElapsedSeconds());
  return 0;
}

static int RunExport(const ExportSwitches& s) {
  if (!s.stac.empty()) return RunStac(s);
  if (s.output.empty()) Fail("export", "give -o OUTPUT (or --stac DIR)");
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
    const std::string rel = Store::LooksLikeStore(s.input) ? InsideStore(s.input, s.output) : "";
    std::optional<Store> store;
    // Recorded in the manifest: refused before the work while an engine, align or compose
    // writes the store (the lock is not held across the export, which would shut them out).
    if (!rel.empty()) {
      LockStoreForChange(store.emplace(Store::Open(s.input)), "rolamos export");
      fs::create_directories(fs::path(s.output).parent_path());  // e.g. STORE/exports, made on first use
    }
    ExportCog(source_path, s.output, c, on_progress);
    progress.Done();
    if (!rel.empty()) {
      try {
        store->RecordExport({rel, "cog"});
      } catch (const Error& e) {
        Fail(s.output, std::string("was written, but is not recorded in the store: ") + e.what());
      }
      std::printf("recorded in the store: rolamos serve hands it out at /files/%s\n", rel.c_str());
    }
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
  cmd->add_option("-o,--output", s->output,
                  "output file (.tif, .png, .jpg); a --cog written inside the store is recorded in it and served");
  cmd->add_option("--region", s->region, "x,y,w,h in full-resolution pixels (default: all)");
  auto* level = cmd->add_option("--level", s->level, "read this pyramid level as stored");
  cmd->add_option("--scale", s->scale, "output scale in (0, 1]")->excludes(level);
  cmd->add_option("--patch", s->patch, "export this patch of a store");
  cmd->add_flag("--cog", s->cog, "write a Cloud Optimized GeoTIFF with GDAL's COG driver");
  cmd->add_option("--stac", s->stac,
                  "a STAC catalogue directory: the georeferenced mosaic as an Item (COG, thumbnail, footprint in "
                  "WGS 84, proj:epsg, gsd, time span) added to DIR/catalog.json");
  cmd->add_option("--stac-id", s->stac_options.id, "with --stac: the item's id (default: the store's name)");
  cmd->add_option("--title", s->stac_options.title, "with --stac: the item's title");
  cmd->add_option("--datetime", s->stac_options.datetime,
                  "with --stac: the survey's time span START/END (RFC 3339; default: the frames' file times)");
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_option("--jpeg-quality", s->jpeg_quality, "quality of .jpg output")
      ->capture_default_str();
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] {
    // -o is required unless the export is a catalogue entry (--stac DIR names where it goes).
    if (s->output.empty() && s->stac.empty()) throw CLI::RequiredError("--output (or --stac DIR)");
    *run = [s] { return RunExport(*s); };
  });
}

}  // namespace rolamos::cli
