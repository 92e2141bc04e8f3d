#include <cstdio>

#include "command.h"
#include "rolamos/global_align.hpp"
#include "rolamos/georeference.hpp"
#include "util/progress.h"

namespace rolamos::cli {

struct AlignSwitches {
  std::string store;
  AlignOptions options;
  std::string navigation, crs;
  NavigationCamera camera;
  bool quiet = false;
};

static int RunAlign(const AlignSwitches& s) {
  AlignOptions o = s.options;
  if (!s.navigation.empty()) o.navigation = ReadNavigationCsv(s.navigation, FrameCamera(Store::Open(s.store), s.camera), s.crs);
  Progress progress("align", s.quiet);
  const AlignSummary r = AlignStore(Store::Open(s.store), o, [&](double f) { progress.Update(f); });
  progress.Done();
  if (r.navigation_frames > 0)
    std::printf("navigation of %d frames: frame centres %.3f m from it before, %.3f m after (median)\n",
                r.navigation_frames, r.navigation_before_m, r.navigation_after_m);
  if (!r.corrected) {
    std::printf("%s: %d frames, %d of %d loop pairs matched, loop error %.2f px: %s; placements left as they are, %.1f s\n",
                s.store.c_str(), r.frames, r.pairs_found, r.pairs_tried, r.loop_error_before_px,
                r.pairs_found ? "the loops already close" : "no revisited ground found", r.seconds);
    return 0;
  }
  std::printf("%s: %d frames aligned, %d of %d loop pairs matched, loop error %.2f -> %.2f px, %.1f s; "
              "run `rolamos compose %s` to draw the aligned mosaic\n",
              s.store.c_str(), r.frames, r.pairs_found, r.pairs_tried, r.loop_error_before_px,
              r.loop_error_after_px, r.seconds, s.store.c_str());
  return 0;
}

void AddAlignCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<AlignSwitches>();
  auto* cmd = app.add_subcommand("align", "Loop closure: match revisited ground, correct every frame's placement together");
  cmd->add_option("store", s->store, "the store (composed once, so the patches are placed)")->required();
  cmd->add_option("--frames", s->options.frames_dir, "folder of the frames, when they moved since `mosaic`");
  cmd->add_option("--model", s->options.model, "correction per frame: affine or similarity")->capture_default_str();
  cmd->add_option("--radius", s->options.search_radius, "try frames closer than this x frame width")->capture_default_str();
  cmd->add_option("--min-gap", s->options.min_index_gap, "frames closer in the sequence are not loop pairs")->capture_default_str();
  cmd->add_option("--pairs", s->options.max_pairs_per_frame, "nearest candidates tried per frame")->capture_default_str();
  cmd->add_option("--min-inliers", s->options.min_inliers, "homography inliers a loop pair needs")->capture_default_str();
  cmd->add_option("--min-loop-error", s->options.min_loop_error_px, "loops closing better than this (px RMS) are left alone")
      ->capture_default_str();
  cmd->add_option("--navigation", s->navigation,
                  "also pull every frame towards its navigation: CSV of per-frame georeference or of vehicle navigation "
                  "(as compose --navigation)");
  cmd->add_option("--navigation-weight", s->options.navigation_weight, "of a navigation point against a matched one")
      ->capture_default_str();
  cmd->add_option("--focal", s->camera.focal_px, "focal length in pixels (vehicle navigation)");
  cmd->add_option("--crs", s->crs, "CRS of eastings/northings without an epsg column, e.g. EPSG:32755");
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunAlign(*s); }; });
}

}  // namespace rolamos::cli
