#include <cstdio>
#include <string>

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

// "12.3 s" per stage, and where the peak was reached (the first stage that ended at it): which
// stage to look at when memory is short.
static std::string StageLine(const AlignSummary& r) {
  std::string line, peak_at;
  char buf[64];
  for (const auto& st : r.stages) {
    std::snprintf(buf, sizeof buf, "%.1f s", st.seconds);
    line += (line.empty() ? "" : ", ") + st.name + " " + buf;
    if (peak_at.empty() && st.peak_mib >= r.stages.back().peak_mib) peak_at = st.name;
  }
  std::snprintf(buf, sizeof buf, "%.0f MiB", r.stages.empty() ? 0.0 : r.stages.back().peak_mib);
  return "stages: " + line + "; peak memory " + buf + " (reached in " + peak_at + ")";
}

static int RunAlign(const AlignSwitches& s) {
  AlignOptions o = s.options;
  if (!s.navigation.empty()) o.navigation = ReadNavigationCsv(s.navigation, FrameCamera(Store::Open(s.store), s.camera), s.crs);
  Progress progress("align", s.quiet);
  const AlignSummary r = AlignStore(Store::Open(s.store), o, [&](double f) { progress.Update(f); });
  progress.Done();
  if (r.frames_described > 0)
    std::printf("%d frames had no stored features and were read and described again\n", r.frames_described);
  std::printf("edges: %d from the engine, %d of %d by appearance, %d of %d loop closures; %d found false and dropped\n",
              r.online_edges, r.retrieval_edges, r.retrieval_tried, r.loop_edges, r.loop_tried, r.edges_dropped);
  if (r.rejoin_tried > 0)
    std::printf("the map was in parts: %d of %d pairs across them matched again with fewer inliers asked\n",
                r.rejoin_edges, r.rejoin_tried);
  if (r.chain_break_px > o.chain_break_px)
    std::printf("the engine's chain was broken by %.0f px (a group of frames pulled away by links that agree with "
                "each other, not with it): solved again with the chain first\n", r.chain_break_px);
  if (r.edges_inconsistent > 0) {
    std::printf("%d appearance edges disagreed with the rest of the map and were left out:\n", r.edges_inconsistent);
    for (size_t k = 0; k < r.rejected_joins.size() && k < 10; ++k)
      std::printf("  %d joining %s: %s\n", r.rejected_joins[k].edges, r.rejected_joins[k].joined.c_str(),
                  r.rejected_joins[k].reason.c_str());
    if (r.rejected_joins.size() > 10) std::printf("  ... and %zu more sets\n", r.rejected_joins.size() - 10);
  }
  if (r.navigation_frames > 0)
    std::printf("navigation of %d frames: frame centres %.3f m from it before, %.3f m after (median)\n",
                r.navigation_frames, r.navigation_before_m, r.navigation_after_m);
  if (r.frames_replaced > 0)
    std::printf("%d frames sat far off their own edges after the solve and were placed again from them\n",
                r.frames_replaced);
  if (r.doubtful_regions.empty()) {
    std::printf("confidence: every frame within %.2f px (median uncertainty %.2f px)\n",
                std::max(2.0, 5 * r.median_uncertainty_px), r.median_uncertainty_px);
  } else {
    std::printf("warning: the map is unsure in %zu region%s (median uncertainty %.2f px; sidecar field "
                "uncertainty_px, the viewer's confidence layer, rolamos info):\n",
                r.doubtful_regions.size(), r.doubtful_regions.size() == 1 ? "" : "s", r.median_uncertainty_px);
    for (size_t k = 0; k < r.doubtful_regions.size() && k < 5; ++k) {
      const auto& d = r.doubtful_regions[k];
      std::printf("  patch %d, frames %d-%d (%d): uncertainty up to %.1f px%s\n", d.patch, d.first_frame, d.last_frame,
                  d.frames, d.worst_uncertainty_px,
                  d.doubtful_frames ? (", " + std::to_string(d.doubtful_frames) + " far off their own edges").c_str() : "");
    }
  }
  if (!r.stages.empty()) std::printf("%s\n", StageLine(r).c_str());
  std::string parts;
  for (size_t c = 0; c < r.component_frames.size() && c < 8; ++c)
    parts += (c ? ", " : "") + std::to_string(r.component_frames[c]);
  if (r.component_frames.size() > 8) parts += ", ...";
  // Parts that share no ground are placed side by side: said only when there are several.
  const std::string layout = r.components == 1 ? "1 part"
                                               : std::to_string(r.components) + " parts (" + parts +
                                                     " frames), placed side by side where they share no ground";
  std::printf("%s: %d frames in %s; edge error %.2f -> %.2f px, %.1f s; run `rolamos compose %s` to draw the map\n",
              s.store.c_str(), r.frames, layout.c_str(), r.rms_before_px, r.rms_after_px, r.seconds, s.store.c_str());
  return 0;
}

void AddAlignCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<AlignSwitches>();
  auto* cmd = app.add_subcommand(
      "align", "The global map: every frame of the survey placed at once (engine links, appearance retrieval, loop "
               "closures; robust adjustment)");
  cmd->add_option("store", s->store, "the store")->required();
  cmd->add_option("--frames", s->options.frames_dir,
                  "folder of the frames, for patches written without stored features (an older rolamos)");
  cmd->add_option("--candidates", s->options.retrieval_candidates, "most similar frames tried per frame (0 = no retrieval)")
      ->capture_default_str();
  cmd->add_option("--loops", s->options.loops_per_frame, "spatial neighbours tried per frame (0 = none)")->capture_default_str();
  cmd->add_option("--min-gap", s->options.min_index_gap, "frames of one patch closer in the sequence are not loop pairs")
      ->capture_default_str();
  cmd->add_option("--min-inliers", s->options.min_inliers, "RANSAC inliers an edge needs")->capture_default_str();
  cmd->add_option("--rejoin-candidates", s->options.rejoin_candidates,
                  "when the map is in parts, frames tried again per frame among the other parts' (0 = never)")
      ->capture_default_str();
  cmd->add_option("--rejoin-min-inliers", s->options.rejoin_min_inliers,
                  "RANSAC inliers an edge between parts needs then")
      ->capture_default_str();
  cmd->add_option("--pairs-per-edge", s->options.pairs_per_edge,
                  "matched pixels an edge's homography is fitted to: more are a truer map, for time")
      ->capture_default_str();
  cmd->add_option("--points-per-edge", s->options.points_per_edge,
                  "points at which the solve holds each edge's homography (0 = every pair): memory grows with them")
      ->capture_default_str();
  cmd->add_option("--loss", s->options.loss_px, "edge RMS (px) beyond which an edge is discounted (Cauchy)")
      ->capture_default_str();
  cmd->add_option("--scatter-floor", s->options.scatter_floor_px,
                  "each edge weighs as the inverse of its pairs' scatter about its homography, floored at this (px; "
                  "0 = every edge by its pairs alone)")
      ->capture_default_str();
  cmd->add_option("--edge-loss", s->options.edge_loss_px,
                  "each edge's homography fitted to its pairs under a Cauchy loss from this many px (0 = least squares)")
      ->capture_default_str();
  cmd->add_option("--navigation", s->navigation,
                  "pull every camera towards its navigation: CSV of per-frame georeference or of vehicle navigation "
                  "(as compose --navigation)");
  cmd->add_option("--navigation-sigma", s->options.navigation_sigma_m, "how far (m, 1 sigma) a centre may stray from it")
      ->capture_default_str();
  cmd->add_option("--focal", s->camera.focal_px, "focal length in pixels (vehicle navigation)");
  cmd->add_option("--crs", s->crs, "CRS of eastings/northings without an epsg column, e.g. EPSG:32755");
  cmd->add_option("--threads", s->options.threads, "0 = one per core")->capture_default_str();
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunAlign(*s); }; });
}

}  // namespace rolamos::cli
