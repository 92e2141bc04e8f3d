#include <cmath>
#include <cstdio>

#include "command.h"
#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/georeference.hpp"
#include "rolamos/link_patches.hpp"
#include "store/writer_lock.h"
#include "util/memory.h"
#include "util/progress.h"

namespace rolamos::cli {

struct ComposeSwitches {
  std::string store;
  std::string navigation, crs;
  NavigationCamera camera;
  long long max_pixels = 0;
  double cache_mb = 256;
  TiffSwitches tiff{"webp", 90, 256, 0};
  LinkOptions link;
  bool relink = true;
  bool restart = false;
  bool no_exposure = false;
  double altitude_m = 0;
  int chunk_px = 4096;
  std::string blend = "feather";
  int bands = 5;
  std::string shard;  // "I/N"
  bool finish = false;
  bool status = false;
  bool quiet = false;
};

static int RunShardStatus(const ComposeSwitches& s) {
  const ShardStatus st = ComposeShardStatus(Store::Open(s.store));
  if (!st.split) {
    std::printf("%s: not split into shards\n", s.store.c_str());
    return 0;
  }
  std::string pending;
  for (int k : st.pending) pending += (pending.empty() ? "" : ",") + std::to_string(k);
  // The last line is the list alone, for a driver script (sbatch --array=LIST).
  std::printf("%s: %lld chunks in %d shards; %zu shards not done\n%s\n", s.store.c_str(), st.chunks, st.shards,
              st.pending.size(), pending.empty() ? "none" : pending.c_str());
  return 0;
}

static int RunCompose(const ComposeSwitches& s) {
  if (s.altitude_m < 0 || (s.altitude_m > 0 && !(s.camera.focal_px > 0)))
    throw rolamos::Error("compose: --altitude needs a positive altitude and --focal (pixels) for the local frame's pixel size");
  if (s.altitude_m > 0 && !s.navigation.empty())
    throw rolamos::Error("compose: --altitude gives a local frame for surveys without navigation; with --navigation, "
                "vehicle altitude goes in the navigation CSV");
  if (s.status) return RunShardStatus(s);
  ComposeOptions o;
  if (!s.shard.empty()) {
    int i = 0, n = 0;
    char rest = 0;
    if (std::sscanf(s.shard.c_str(), "%d/%d%c", &i, &n, &rest) != 2)
      throw rolamos::Error("compose: --shard " + s.shard + " is not I/N (e.g. 3/8)");
    o.shard = i;
    o.shards = n;
  }
  o.finish = s.finish;
  o.chunk_px = s.chunk_px;
  o.bands = s.blend == "multiband" ? s.bands : 0;
  const bool sharded = o.shards > 0 || o.finish;
  if (sharded && !o.finish && (!s.navigation.empty() || s.altitude_m > 0))
    throw rolamos::Error("compose: --navigation and --altitude go with --finish, which writes the mosaic");
  o.max_pixels = s.max_pixels;
  o.cache_mb = s.cache_mb;
  o.tiff = ToWriteOptions(s.tiff);
  o.threads = s.tiff.threads;
  o.restart = s.restart;
  o.exposure = !s.no_exposure;
  std::string error;
  if (!o.IsValid(&error)) throw rolamos::Error("compose: " + error + " (--shard/--finish/--restart)");
  Store store = Store::Open(s.store);
  // Linking, composing and georeferencing each change the store: held once across them, so that
  // no engine or align comes in between. A shard writes only its share of the partial mosaic.
  const auto lock = sharded && !o.finish ? nullptr : LockStoreForChange(store, "rolamos compose");
  // Shards must all see one store: linking (which rewrites sidecars) is left to a plain compose or
  // to align before the split.
  if (s.relink && !sharded) {
    // Patches that lost the thread are placed by recognising where their first frames were seen.
    Progress linking("link", s.quiet);
    const LinkSummary l = LinkPatches(store, s.link, [&](double f) { linking.Update(f); });
    linking.Done();
    for (const auto& [id, to] : l.linked) std::printf("patch %d linked to patch %d by place recognition\n", id, to);
    for (const auto& [id, why] : l.unlinked) std::printf("patch %d not linked: %s\n", id, why.c_str());
  }
  Progress progress("compose", s.quiet);
  ComposeResult r = ComposeMosaic(store, o, [&](double f) { progress.Update(f); });
  progress.Done();
  if (!r.discarded.empty()) std::printf("not resumed: %s\n", r.discarded.c_str());
  if (r.chunks_resumed > 0 && !o.finish)
    std::printf("resumed: %lld of %lld chunks were done by an interrupted run\n", r.chunks_resumed, r.chunks);
  for (const auto& [id, why] : r.left_out) std::printf("patch %d left out: %s\n", id, why.c_str());
  if (!r.written) {
    std::printf("%s shard %d/%d: %lld of its %lld chunks rendered (%lld done before) from %d patches, %.1f s; "
                "when every shard is done: rolamos compose %s --finish\n",
                s.store.c_str(), o.shard, o.shards, r.chunks_rendered, r.shard_chunks,
                r.shard_chunks - r.chunks_rendered, r.patches_used, progress.ElapsedSeconds(), s.store.c_str());
    return 0;
  }
  if (!s.navigation.empty()) {
    const NavigationCamera camera = FrameCamera(store, s.camera);
    GeoreferenceResult g = GeoreferenceMosaic(store, ReadNavigationCsv(s.navigation, camera, s.crs));
    std::printf("georeferenced from %d frames (%s): pixel %.4g m, residual median %.3f m, max %.3f m\n",
                g.frames_used, g.georef.crs.c_str(), std::hypot(g.georef.geotransform[1], g.georef.geotransform[4]),
                g.median_residual_m, g.max_residual_m);
  }
  if (s.navigation.empty() && s.altitude_m > 0) {
    const Georef g = GeoreferenceLocal(store, s.altitude_m / s.camera.focal_px);
    std::printf("local engineering frame (no navigation): %.4g m a pixel, origin at the first frame's centre\n",
                g.geotransform[1]);
  }
  const double seconds = progress.ElapsedSeconds();
  std::printf("%s/mosaic.tif: %lld x %lld at scale %.4g from %d patches, %s\n", s.store.c_str(), r.width,
              r.height, r.scale, r.patches_used, TimeRateMemory(seconds, double(r.width) * double(r.height)).c_str());
  return 0;
}

void AddComposeCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<ComposeSwitches>();
  auto* cmd = app.add_subcommand(
      "compose", "Place the store's patches in one frame and compose mosaic.tif, out of core");
  cmd->add_option("store", s->store, "the store")->required();
  cmd->add_option("--navigation", s->navigation,
                  "CSV of per-frame georeference (frame, epsg, gt0..gt5[, sequence]) or of vehicle navigation "
                  "(frame, easting,northing or lat,lon, altitude, heading) to place the mosaic on the map");
  cmd->add_option("--focal", s->camera.focal_px, "focal length in pixels (vehicle navigation)");
  cmd->add_option("--altitude", s->altitude_m,
                  "without navigation: camera altitude in metres; with --focal, georeferences the mosaic in a "
                  "local engineering frame (metres, origin at the first frame)");
  cmd->add_option("--crs", s->crs, "CRS of eastings/northings without an epsg column, e.g. EPSG:32755");
  cmd->add_option("--max-pixels", s->max_pixels, "scale the mosaic to fit this many pixels (0 = full)")
      ->capture_default_str();
  cmd->add_option("--cache-mb", s->cache_mb, "tile cache for reading patches")->capture_default_str();
  cmd->add_option("--frames", s->link.frames_dir, "folder of the frames (place recognition reads them), when moved since `mosaic`");
  cmd->add_flag("--restart", s->restart, "start over instead of finishing an interrupted compose");
  cmd->add_option("--shard", s->shard,
                  "I/N: render only shard I of N into the partial mosaic (one cluster job each; the first records "
                  "the split, a shard run again does only what is missing); then --finish")
      ->check([](const std::string& v) { return v.find('/') == std::string::npos ? "expected I/N" : ""; });
  cmd->add_option("--blend", s->blend,
                  "feather (weights fading over 64 px at patch borders) or multiband (Laplacian pyramids across "
                  "seams placed where the patches' weights cross; hides exposure and colour steps)")
      ->check(CLI::IsMember({"feather", "multiband"}))
      ->capture_default_str();
  cmd->add_option("--bands", s->bands, "pyramid levels of --blend multiband")->capture_default_str();
  cmd->add_option("--chunk", s->chunk_px,
                  "mosaic pixels per chunk side (power of two): the unit of parallel work, of resuming and of shards")
      ->capture_default_str();
  cmd->add_flag("--finish", s->finish, "write mosaic.tif from the shards, once every one is done");
  cmd->add_flag("--status", s->status, "print the shards not done yet (the last line: a list for sbatch --array)");
  cmd->add_flag("!--no-link", s->relink, "do not look for where unlinked patches belong");
  cmd->add_flag("--no-exposure", s->no_exposure, "no matching of each patch's brightness to its neighbours'");
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunCompose(*s); }; });
}

}  // namespace rolamos::cli
