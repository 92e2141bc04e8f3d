#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <set>
#include <thread>

#include <signal.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/store.hpp"
#include "store/writer_lock.h"
#include "util/files.h"
#include "util/progress.h"

namespace rolamos::cli {

struct MosaicSwitches {
  std::string input, output;
  MosaickerOptions options;
  // Patches are intermediate (compose re-encodes them) and written at the camera's rate: the
  // engine's own default codec (JPEG with the alpha as a mask).
  TiffSwitches tiff = FromWriteOptions(MosaickerOptions::PatchWriteOptions());
  bool no_bilateral = false, no_temporal = false, no_clahe = false, no_sift_upsample = false, no_fundamental = false,
       no_kalman = false, no_ecc = false, no_cross_check = false, no_recover = false, no_patch_fit = false, no_adjust = false,
       no_follow_back = false, no_features_ahead = false, fixed_focal = false,
       no_flat_field = false, no_exposure = false, no_water_colour = false;
  bool quiet = false;
  bool fov_given = false;
  bool live = false;
  LiveOptions live_options;
  LiveViewerSwitches viewer;  // --serve
};

// SIGINT/SIGTERM end a run cleanly (the open patch is written); a second one says that the patch
// is still being written (an impatient Ctrl-C must not lose it); a third abandons it.
static std::atomic<bool> g_stop{false};
static std::atomic<int> g_signals{0};
static void OnStopSignal(int sig) {
  g_stop = true;
  const int n = ++g_signals;
  if (n == 2) {
    static const char kMessage[] = "\nrolamos: stopping: writing the open patch (once more to abandon it)\n";
    [[maybe_unused]] const ssize_t w = write(STDERR_FILENO, kMessage, sizeof kMessage - 1);
  } else if (n >= 3) {
    std::signal(sig, SIG_DFL);
    std::raise(sig);
  }
}

// A stop (Ctrl-C, SIGTERM) ends a live run, or a run over a folder, list or video as the end of
// its input would: the frames read are mapped and the open patch written.
static void CatchStopSignals() {
  struct sigaction sa {};
  sa.sa_handler = OnStopSignal;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

static std::string StatusJson(const LiveStatus& st) {
  nlohmann::json j = {{"running", st.running},
                      {"frames_received", st.frames_received},
                      {"frames_registered", st.frames_registered},
                      {"frames_rejected", st.frames_rejected},
                      {"frames_skipped", st.frames_skipped},
                      {"coverage_lost", st.coverage_lost},
                      {"frames_incomplete", st.frames_incomplete},
                      {"backlog_max", st.backlog_max},
                      {"backlog_bound", st.backlog_bound},
                      {"frames_shedding", st.frames_shedding},
                      {"shedding", st.shedding},
                      {"patches", st.patches},
                      {"open_patch", st.open_patch},
                      {"last_frame_time", st.last_frame_time},
                      {"latency_ms_p50", st.latency_ms_p50},
                      {"latency_ms_p95", st.latency_ms_p95},
                      {"started", st.started},
                      {"updated", st.updated}};
  return j.dump() + "\n";
}

// The switches' --no-* and codec settings into the engine's options.
static MosaickerOptions EngineOptions(const MosaicSwitches& s) {
  MosaickerOptions o = s.options;
  if (s.live && o.checkpoint_frames == 0) o.checkpoint_frames = 150;
  o.bilateral = !s.no_bilateral;
  o.temporal = !s.no_temporal;
  o.clahe = !s.no_clahe;
  o.sift_upsample = !s.no_sift_upsample;
  o.fundamental = !s.no_fundamental;
  o.kalman = !s.no_kalman;
  if (o.mask == "none") o.mask.clear();
  o.recover = !s.no_recover;
  o.patch_fit = !s.no_patch_fit;
  o.follow_back = !s.no_follow_back;
  o.features_ahead = !s.no_features_ahead;
  o.adjust_patches = !s.no_adjust;
  o.estimate_focal = !s.fixed_focal;
  o.flat_field = !s.no_flat_field;
  o.exposure = !s.no_exposure;
  o.water_colour = !s.no_water_colour;
  o.ecc = !s.no_ecc;
  o.cross_check = !s.no_cross_check;
  o.tiff = ToWriteOptions(s.tiff);
  return o;
}

// A live run: its status in STORE/live, the viewer in this process with --serve.
static MosaicSummary RunLive(MosaicSwitches& s, Store& store, const MosaickerOptions& o,
                             const LiveViewerStarter& start_viewer,
                             const std::function<void(const FrameReport&, int)>& on_frame) {
  s.live_options.stop = &g_stop;
  const std::string status_dir = store.dir() + "/live";
  std::filesystem::create_directories(status_dir);
  std::shared_ptr<void> viewer;  // stops the viewer when released
  if (s.viewer.port >= 0) {
    // The page may open before the first frame: it sees a run that has started.
    LiveStatus starting;
    starting.running = true;
    WriteFileAtomic(status_dir + "/status.json", StatusJson(starting));
    viewer = start_viewer(store, s.viewer);
  }
  std::atomic<bool> status_failed{false};
  MosaicSummary sum = MosaicLive(s.input, store, o, s.live_options,
                                 [&](const LiveStatus& st) {
                                   // The status is for watching the run: failing to write it (a
                                   // full disk) must not stop the map; said once.
                                   try {
                                     WriteFileAtomic(status_dir + "/status.json", StatusJson(st), /*durable=*/false);
                                   } catch (const Error& e) {
                                     if (!status_failed.exchange(true))
                                       std::fprintf(stderr, "rolamos: warning: %s (the run goes on without a status)\n",
                                                    e.what());
                                   }
                                 },
                                 on_frame);
  viewer.reset();
  return sum;
}

// Patches the adjustment did not fit keep their online placements, which drift. Where the frames
// fit no plane seen through a pinhole, the likely cause is a lens that distorts (a 90-degree lens
// uncalibrated: one patch at 5.7 px after adjustment, the map hundreds of pixels off).
// A patch of one or two frames has nothing to adjust: not said.
static void PrintUnadjusted(const MosaicSummary& sum, bool calibrated) {
  std::string which;
  int failed = 0;
  const std::set<int> trivial(sum.trivial_patches.begin(), sum.trivial_patches.end());
  for (const auto& [id, why] : sum.unadjusted_why) {
    if (trivial.count(id)) continue;
    if (++failed <= 3) which += (failed > 1 ? "; patch " : "patch ") + std::to_string(id) + ": " + why;
  }
  if (failed == 0) return;
  if (failed > 3) which += "; ...";
  std::printf("%d of %d patches kept their online placements, the adjustment did not fit them (%s)\n", failed,
              sum.adjusted + sum.unadjusted, which.c_str());
  if (!sum.misfit_patches.empty() && !calibrated)
    std::printf("frames that fit no flat ground seen through a pinhole camera: a lens that distorts? Give its "
                "calibration (--calibration FILE), or --calibration auto; or ground far from flat\n");
}

// Which frames were rejected and why, the first few: a count alone leaves the user to search the
// sidecars (and a run that placed nothing has none).
static void PrintRejected(const MosaicSummary& sum) {
  if (sum.rejected_frames.empty()) return;
  constexpr size_t kShown = 5;
  std::string which;
  for (size_t i = 0; i < sum.rejected_frames.size() && i < kShown; ++i) {
    const RejectedFrame& r = sum.rejected_frames[i];
    which += (i ? "; " : "") + std::string("frame ") + std::to_string(r.index) + " " +
             std::filesystem::path(r.source).filename().string() + ", " + r.reason;
  }
  if (sum.rejected_frames.size() > kShown)
    which += "; and " + std::to_string(sum.rejected_frames.size() - kShown) + " more";
  std::printf("rejected: %s%s\n", which.c_str(), sum.patches > 0 ? " (all in the patches' sidecars)" : "");
}

// The one-line summary, then what each stage cost per frame and per keyframe.
static void PrintSummary(const MosaicSwitches& s, const MosaicSummary& sum, int input_frames) {
  if (!sum.preview_problem.empty())
    std::printf("the open patch's preview could not be written (the patches are): %s\n", sum.preview_problem.c_str());
  if (!sum.calibration_note.empty()) std::printf("%s\n", sum.calibration_note.c_str());
  if (!sum.mask_note.empty()) std::printf("%s\n", sum.mask_note.c_str());
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  std::printf("%s: %d frames, %d stitched (%d keyframes, %d blended, %d described, %d on a second chance), %d rejected, "
              "%d patches, %.1f s (%.1f frames/s), CPU %.0f %% of %u cores, peak memory %.0f MiB\n",
              s.output.c_str(), sum.frames, sum.stitched, sum.keyframes, sum.blended, sum.described, sum.recovered,
              sum.rejected, sum.patches, sum.seconds, sum.frames / std::max(sum.seconds, 1e-9),
              100.0 * sum.cpu_seconds / std::max(sum.seconds, 1e-9) / cores, cores, sum.peak_rss_mb);
  PrintRejected(sum);
  if (sum.unadjusted > 0) PrintUnadjusted(sum, !s.options.calibration.empty());
  if (s.live)
    std::printf("live: %d frames skipped to keep up, coverage lost after %d of them, %d mapped while shedding load%s\n",
                sum.frames_skipped, sum.coverage_lost, sum.frames_shedding,
                g_stop ? "; stopped by a signal, the open patch written" : "");
  else if (sum.stopped)
    std::printf("stopped by a signal after %d frames%s: the open patch written, the frames after them not mapped\n",
                sum.frames, input_frames > 0 ? (" of " + std::to_string(input_frames)).c_str() : "");
  if (sum.stitched == 0) {
    std::printf("no frame placed: the store holds no patch from this run\n");
    return;
  }
  std::string stages, per_key;
  for (const auto& [name, sec] : sum.stage_seconds) {
    char b[64];
    std::snprintf(b, sizeof b, "%s%s %.0f ms", stages.empty() ? "" : ", ", name.c_str(),
                  1000.0 * sec / std::max(1, sum.frames));
    stages += b;
    if (std::find(sum.keyframe_stages.begin(), sum.keyframe_stages.end(), name) == sum.keyframe_stages.end()) continue;
    std::snprintf(b, sizeof b, "%s%s %.0f ms", per_key.empty() ? "" : ", ", name.c_str(),
                  1000.0 * sec / std::max(1, sum.keyframes));
    per_key += b;
  }
  if (sum.RestCpuSeconds() > 0 && !stages.empty()) {
    char b[64];
    std::snprintf(b, sizeof b, ", rest %.0f ms", 1000.0 * sum.RestCpuSeconds() / std::max(1, sum.frames));
    stages += b;
  }
  std::string followed;
  if (sum.track_scale > 0)
    followed = sum.track_scale >= 1 ? "; followed at full size"
                                    : "; followed at 1/" + std::to_string(std::lround(1 / sum.track_scale)) + " size";
  if (sum.features_ahead > 0) followed += "; " + std::to_string(sum.features_ahead) + " described ahead";
  std::printf("per frame (CPU, all threads%s): %s\n", followed.c_str(), stages.c_str());
  if (!per_key.empty()) std::printf("per keyframe: %s\n", per_key.c_str());
  std::printf("Look at it: build/rolamos info %s; build/rolamos export %s --patch 1 --scale 0.25 "
              "-o patch1.jpg\n", s.output.c_str(), s.output.c_str());
}

static int RunMosaic(MosaicSwitches s, const LiveViewerStarter& start_viewer) {
  const MosaickerOptions o = EngineOptions(s);
  std::string error;
  if (!o.IsValid(&error)) Fail("mosaic", error);
  // Before the store is made: bad settings or a mistyped input must not leave an empty store.
  if (s.live && !s.live_options.IsValid(&error)) Fail("mosaic --live", error);
  if (s.viewer.port >= 0 && !s.live)
    Fail("mosaic", "serving while mapping needs a live run (rolamos serve STORE serves a store once written)");
  if (!s.viewer.navigation.empty() && s.viewer.port < 0)
    Fail("mosaic", "navigation georeferences the live view, which needs --serve (compose --navigation "
                   "georeferences the map)");
  if (!s.live) CheckMosaicInput(s.input);
  StoreOptions so;
  if (!o.calibration.empty()) so.camera = {{"calibration_file", o.calibration}};
  else if (s.fov_given) so.camera = {{"fov_deg", o.fov_deg}};
  Store store = Store::LooksLikeStore(s.output) ? Store::Open(s.output) : Store::Create(s.output, so);
  // Before anything is written into it (a live run's status): a store another engine writes is
  // refused here, its files untouched.
  const auto lock = LockStoreForChange(store, "a rolamos mosaic engine");
  Progress progress("mosaic", s.quiet);
  auto on_frame = [&](const FrameReport& r, int total) {
    char detail[200];
    std::snprintf(detail, sizeof detail, "frame %d %s%s%s patch %d, %d/%d inliers", r.index,
                  r.status.c_str(), r.reason.empty() ? "" : " (", r.reason.empty() ? "" : (r.reason + ")").c_str(),
                  r.patch_id, r.inliers, r.matches);
    progress.Update(total > 0 ? double(r.index + 1) / total : 0.0, detail);
  };
  CatchStopSignals();
  int input_frames = -1;
  const MosaicSummary sum =
      s.live ? RunLive(s, store, o, start_viewer, on_frame)
             : MosaicInput(
                   s.input, store, o,
                   [&](const FrameReport& r, int total) {
                     input_frames = total;
                     on_frame(r, total);
                   },
                   &g_stop, [&](const std::string& note) { progress.Update(0.0, note); });
  progress.Done();
  PrintSummary(s, sum, input_frames);
  return sum.stitched > 0 ? 0 : 1;
}

// Live: where frames come from as they arrive, the viewer while mapping, the backlog.
static void AddLiveSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  cmd->add_flag("--live", s->live,
                "map frames as they arrive until the stream ends, SIGINT/SIGTERM (the open patch is written) or "
                "--idle-timeout; frames that arrive while the engine is busy are skipped; STORE/live/status.json "
                "says where it stands");
  cmd->add_option("--serve", s->viewer.port,
                  "live: serve the viewer on this port while mapping (0: any free port): the patches as they are "
                  "written, and the open patch as it grows");
  cmd->add_option("--bind", s->viewer.bind, "with --serve: address to listen on")->capture_default_str();
  cmd->add_option("--navigation", s->viewer.navigation,
                  "with --serve: the vehicle's navigation CSV as it grows (compose --navigation's columns): "
                  "georeferences the live view as fixes arrive; lines that do not parse are skipped with a warning");
  cmd->add_option("--crs", s->viewer.navigation_crs, "with --navigation: CRS of eastings/northings without an epsg column");
  cmd->add_option("--focal", s->viewer.focal_px, "with --navigation: focal length in pixels (default: the camera's)");
  cmd->add_option("--max-waiting", s->live_options.max_waiting,
                  "live: frames waiting or being mapped at once, at most; beyond it the oldest waiting are skipped")
      ->capture_default_str();
  cmd->add_option("--shed-overlap", s->live_options.shed_describe_overlap,
                  "live: while the engine is behind (half the backlog), keyframes are described only when they "
                  "overlap the last described one less than this, instead of --describe-overlap, and recovery's dense "
                  "last try is left out: frames are mapped faster, at some cost in accuracy, rather than skipped; 1 = "
                  "never")
      ->capture_default_str();
  cmd->add_option("--preview-interval", s->live_options.preview_s,
                  "live: seconds between previews of the open patch (STORE/live/preview.json; 0 = none)")
      ->capture_default_str();
  cmd->add_option("--idle-timeout", s->live_options.idle_timeout_s, "live: end after this many seconds without a frame (0 = never)")
      ->capture_default_str();
}

// The store, the frames' overlays, lens and filters.
static void AddFrameSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  auto& o = s->options;
  cmd->add_option("--checkpoint-frames", o.checkpoint_frames,
                  "close (write) the open patch after this many frames, so a crash loses at most these (default 0; "
                  "150 with --live)");
  cmd->add_option("-o,--output", s->output, "store to create (or add to)")->required();
  cmd->add_option("--mask", o.mask,
                  "static overlays to leave out of matching and blending: an image of the frames' size, white where "
                  "the frames hold a fixed overlay (timestamp, laser dots, a part of the vehicle); \"auto\" finds "
                  "them in the first frames, or in those after them where the seafloor hardly moves under the first "
                  "(a descent: up to 30 minutes at 30 frames/s read again; a live run reads on, a window of 24 frames ahead "
                  "of the mapping, for up to an hour), or an earlier run's mask in the store (live), and writes "
                  "<store>/static_mask.png; \"none\" for no mask")
      ->capture_default_str();
  cmd->add_option("--calibration", o.calibration,
                  "OpenCV calibration file (YAML/XML/JSON), or \"auto\" to estimate radial "
                  "distortion from the first frames");
  cmd->add_option_function<double>("--fov", [s](double v) { s->options.fov_deg = v; s->fov_given = true; },
                  "without --calibration: the camera's horizontal field of view in water, degrees (default 70); "
                  "each patch's adjustment estimates the focal length from it unless --fixed-focal");
  cmd->add_flag("--no-bilateral", s->no_bilateral, "skip the bilateral filter");
  cmd->add_flag("--no-temporal", s->no_temporal, "skip the temporal filter");
  cmd->add_flag("--no-clahe", s->no_clahe, "no contrast normalisation of the detection image");
}

// Following frames (Lucas-Kanade).
static void AddTrackingSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  auto& o = s->options;
  cmd->add_option("--track-pixels", o.track_pixels,
                  "frames are followed (Lucas-Kanade) halved until they hold at most this many pixels")
      ->capture_default_str();
  cmd->add_option("--track-halve", o.track_halve,
                  "halve frames for following at least once all the same: always (video codecs), never (stills), "
                  "auto (always for a video file or stream)")
      ->capture_default_str();
  cmd->add_option("--video-track-pixels", o.video_track_pixels,
                  "frames halved for following (--track-halve) are then halved until they hold at most this many "
                  "pixels: large video frames at a quarter")
      ->capture_default_str();
  cmd->add_option("--track-points", o.track_points,
                  "points a keyframe hands on to the frames after it (twice as many on video followed at a quarter)")
      ->capture_default_str();
  cmd->add_option("--track-window", o.track_window,
                  "Lucas-Kanade's window in tracking pixels, for frames followed at full size (5..61; frames "
                  "followed halved use 21, a video followed at a quarter 13)")
      ->capture_default_str();
  cmd->add_option("--track-turn", o.track_turn_deg,
                  "a frame turned more than this many degrees from the one it is followed from is followed in a "
                  "copy turned back (0 = never)")
      ->capture_default_str();
  cmd->add_option("--track-turn-search", o.track_turn_search_deg,
                  "a frame no start could follow is tried once more, turned by what correlates best within this "
                  "many degrees either way, before recovery by SIFT (0 = not tried; 84 places a random walk's "
                  "stills better within each patch, but makes the global map after align worse)")
      ->capture_default_str();
}

// Which frames become keyframes, are described and blended.
static void AddKeyframeSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  auto& o = s->options;
  cmd->add_option("--keyframe-overlap", o.keyframe_overlap,
                  "a frame that overlaps the last keyframe less than this becomes a keyframe (adjusted with the "
                  "patch's others, its features stored); 1 = every frame")
      ->capture_default_str();
  cmd->add_option("--blend-overlap", o.blend_overlap,
                  "a keyframe is blended into the patch image when it overlaps the last blended keyframe less than "
                  "this (the others link and place only); 1 = every keyframe")
      ->capture_default_str();
  cmd->add_option("--keyframe-min-overlap", o.keyframe_min_overlap,
                  "a frame becomes a keyframe when the next one is predicted to overlap the last keyframe less than this")
      ->capture_default_str();
  cmd->add_option("--describe-overlap", o.describe_overlap,
                  "a keyframe followed from the one before is described (its features found and stored for the "
                  "global map and loop closures) when it overlaps the last described keyframe less than this; 1 = "
                  "every keyframe; 0.5: faster on stills, at some cost in accuracy")
      ->capture_default_str();
  cmd->add_option("--still-track-points", o.still_track_points,
                  "points a keyframe taken right after another (stills) hands on to the next; 600 alone: "
                  "stills truer (over 20 surveys 12 % less error within each patch, 3 % less after align) for "
                  "~11 % more CPU; 600 with --still-describe-overlap 0.5: the stills' faster mode, better "
                  "placed within each patch, a worse global map")
      ->capture_default_str();
  cmd->add_option("--still-describe-overlap", o.still_describe_overlap,
                  "a keyframe taken right after another (stills) is described when it overlaps the last described "
                  "keyframe less than this; 1 = every still")
      ->capture_default_str();
  cmd->add_option("--still-blend-overlap", o.still_blend_overlap,
                  "a keyframe taken right after another (stills) is blended when it overlaps the last blended "
                  "keyframe less than this (every other still at 70 % overlap; the others are described and "
                  "adjusted, in the patch image through their neighbours); 1 = every still")
      ->capture_default_str();
}

// Features, matching and the registration's checks.
static void AddMatchingSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  auto& o = s->options;
  cmd->add_option("--features", o.features, "sift, orb or akaze")->capture_default_str();
  cmd->add_option("--max-features", o.max_features, "features per frame")->capture_default_str();
  cmd->add_option("--followed-max-features", o.followed_max_features,
                  "features of a keyframe that frames were followed into before it (video): its neighbours are linked by "
                  "the points followed, SIFT serves loop closures and recovery")
      ->capture_default_str();
  cmd->add_option("--detect-scale", o.detect_scale, "resize before detection (0 = by frame size)")->capture_default_str();
  cmd->add_option("--detect-pixels", o.detect_pixels, "detection image size when --detect-scale is 0")
      ->capture_default_str();
  cmd->add_flag("--no-sift-upsample", s->no_sift_upsample,
                "SIFT without its first octave at twice the detection size: keypoints found on the detection image "
                "halved, half the time for features, 30-60 % more error within each patch (with twice --detect-pixels "
                "still worse than upsampled, and slower)");
  cmd->add_option("--ratio", o.ratio, "ratio test")->capture_default_str();
  cmd->add_flag("--no-cross-check", s->no_cross_check, "keep one-way matches");
  cmd->add_flag("--no-fundamental", s->no_fundamental, "skip F-RANSAC / bilateral epipolar stage");
  cmd->add_option("--epipolar-threshold", o.epipolar_threshold, "pixels")->capture_default_str();
  cmd->add_option("--homography-threshold", o.homography_threshold, "pixels")->capture_default_str();
  cmd->add_option("--min-inliers", o.min_inliers, "fewer means tracking lost")->capture_default_str();
  cmd->add_flag("--no-kalman", s->no_kalman, "no consistency gate");
  cmd->add_flag("--no-recover", s->no_recover,
                "no recovery: a frame is registered to the previous one only, never against the patch's other "
                "frames or image, and rejected frames get no second chance");
}

// Lighting, adjustment, placing and the patches' budgets.
static void AddPatchSwitches(CLI::App* cmd, const std::shared_ptr<MosaicSwitches>& s) {
  auto& o = s->options;
  cmd->add_flag("--no-flat-field", s->no_flat_field,
                "keep the lighting (vignetting, the lights' cone) the survey's frames share");
  cmd->add_flag("--no-exposure", s->no_exposure, "no matching of each frame's exposure to its neighbours'");
  cmd->add_flag("--no-water-colour", s->no_water_colour, "keep the water's colour cast");
  cmd->add_flag("--no-adjust", s->no_adjust,
                "keep the online placements: no adjustment of each patch's frames as cameras over the seafloor plane "
                "when it closes");
  cmd->add_flag("--fixed-focal", s->fixed_focal,
                "adjust each patch with the focal length of --fov as given, instead of estimating it with the poses "
                "(a calibration file's is always held)");
  cmd->add_option("--patch-robust-loss", o.patch_robust_loss_px,
                  "pixels beyond which the patch adjustment's last solve discounts a link's pairs (Cauchy); 0 = the "
                  "Huber loss from a pixel alone, as before session 41")
      ->capture_default_str();
  cmd->add_option("--patch-frames-mb", o.patch_frames_mb,
                  "memory for a patch's keyframes (images and features) until it is written (a patch closes when "
                  "full); the engine holds at most three patches' worth")
      ->capture_default_str();
  cmd->add_flag("--no-follow-back", s->no_follow_back,
                "place a frame followed between two keyframes from the one before alone, not also from the next "
                "(its points followed back into it)");
  cmd->add_flag("--no-features-ahead", s->no_features_ahead,
                "find a frame's features on the engine's thread when it needs them, not ahead on the threads that "
                "read frames (the same map; ahead only while the recent frames all needed theirs)");
  cmd->add_flag("--no-patch-fit", s->no_patch_fit,
                "place each frame from its previous frame alone, not fitted against every patch frame it overlaps");
  cmd->add_flag("--no-ecc", s->no_ecc, "no ECC refinement");
  cmd->add_option("--ecc-scale", o.ecc_scale, "ECC resolution")->capture_default_str();
  cmd->add_option("--ecc-motion", o.ecc_motion, "translation, euclidean, affine or homography")
      ->capture_default_str();
  cmd->add_option("--feather-sigma", o.feather_sigma, "Gaussian sigma / frame size; 0 = average")
      ->capture_default_str();
  cmd->add_option("--patch-megapixels", o.patch_megapixels, "pixel budget of a patch")
      ->capture_default_str();
  cmd->add_option("--patch-memory-mb", o.patch_memory_mb, "memory budget of a patch (0 = none)");
  cmd->add_option("--max-lost", o.max_lost_frames, "failures in a row that close a patch")
      ->capture_default_str();
}

void AddMosaicCommand(CLI::App& app, Runner* run, LiveViewerStarter start_viewer) {
  auto s = std::make_shared<MosaicSwitches>();
  auto* cmd = app.add_subcommand("mosaic", "Mosaic frames (folder, list or video) into a store, online");
  cmd->add_option("input", s->input,
                  "folder of frames, .txt list of frames, or a video; with --live: a folder that grows, a camera "
                  "(/dev/videoN), a stream (rtsp://, udp://) or a GStreamer pipeline ending in appsink")
      ->required();
  AddLiveSwitches(cmd, s);
  AddFrameSwitches(cmd, s);
  AddTrackingSwitches(cmd, s);
  AddKeyframeSwitches(cmd, s);
  AddMatchingSwitches(cmd, s);
  AddPatchSwitches(cmd, s);
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_flag("-q,--quiet", s->quiet, "no progress");
  cmd->callback([s, run, start_viewer] { *run = [s, start_viewer] { return RunMosaic(*s, start_viewer); }; });
}

}  // namespace rolamos::cli
