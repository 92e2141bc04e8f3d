#include "rolamos/compose.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <sstream>

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <ctime>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "compose/patch_blender.h"
#include "util/exposure_gains.h"
#include "compose/quadtree_pyramid.h"
#include "compose/tile_journal.h"
#include "store/writer_lock.h"
#include "util/files.h"
#include "util/homography.h"

namespace rolamos {

bool ComposeOptions::IsValid(std::string* error) const {
  if (max_pixels < 0) {
    *error = "the pixel limit (max_pixels) cannot be negative";
    return false;
  }
  if (feather_px < 1 || feather_px > 1024) {
    *error = "feather width must be 1..1024 pixels";
    return false;
  }
  if (chunk_px < tiff.tile_size || chunk_px > 65536 || (chunk_px & (chunk_px - 1)) != 0) {
    *error = "chunk size " + std::to_string(chunk_px) + " must be a power of two from the tile size (" +
             std::to_string(tiff.tile_size) + ") to 65536";
    return false;
  }
  if (shards < 0 || shards > 100000 || (shards > 0 && !finish && (shard < 1 || shard > shards)) ||
      (shards == 0 && shard != 0) || (finish && shard != 0)) {
    *error = "shard " + std::to_string(shard) + " of " + std::to_string(shards) + " is not one of 1.." + std::to_string(shards);
    return false;
  }
  if (shards > 0 && restart) {
    *error = "a shard cannot restart the split on its own (the other shards share it): delete the partial "
             "mosaic folder, or compose without shards";
    return false;
  }
  if (bands < 0 || bands > 10) {
    *error = "multi-band levels " + std::to_string(bands) + " must be 0 (feathering) to 10";
    return false;
  }
  if (threads < 0) {
    *error = "thread count cannot be negative";
    return false;
  }
  TileCacheOptions cache;
  cache.max_memory_mb = cache_mb;
  if (!cache.IsValid(error)) return false;
  PixelLayout rgba;
  rgba.width = rgba.height = 1024;
  rgba.channels = 4;
  return tiff.IsValid(rgba, error);
}

namespace {

// Everything the pixels depend on: a journal written for other inputs is not resumed.
std::string Fingerprint(const std::vector<PlacedPatch>& placed, const ComposeResult& r,
                        const ComposeOptions& o) {
  std::ostringstream f;
  f.precision(17);
  f << r.width << 'x' << r.height << " scale " << r.scale << " feather " << o.feather_px << " bands " << o.bands << " chunk " << o.chunk_px << " codec "
    << CompressionName(o.tiff.compression) << ' ' << o.tiff.quality << ' ' << o.tiff.tile_size << ' '
    << o.tiff.pyramid << ' ' << o.tiff.zstd_level << ' ' << o.tiff.deflate_level << ' ' << o.tiff.webp_method;
  for (const auto& p : placed) {
    std::error_code ec;
    const auto bytes = std::filesystem::file_size(p.path, ec);
    const auto time = std::filesystem::last_write_time(p.path, ec).time_since_epoch().count();
    // The file's name, not its path: shards on other machines may reach the store by other paths.
    f << '\n' << p.id << ' ' << std::filesystem::path(p.path).filename().string() << ' ' << bytes << ' ' << time;
    for (int k = 0; k < 9; ++k) f << ' ' << p.to_mosaic.val[k];
    for (const auto& l : p.local)
      for (int k = 0; k < 9; ++k) f << ' ' << l.to_mosaic.val[k];
    f << " gain " << p.gain;
  }
  return FingerprintHex(f.str());
}

// A patch's first frame as `G` (patch -> global) draws it: its size against the frame's own (the
// square root of the areas' ratio) and how uneven it is (the longest side against the one opposite).
struct FirstFrameShape {
  double scale = 1, uneven = 1;
};
std::optional<FirstFrameShape> FirstFrameUnder(const cv::Matx33d& G, const PatchSidecar& s) {
  if (!s.frame_size || s.frames.empty()) return std::nullopt;
  const double w = (*s.frame_size)[0], h = (*s.frame_size)[1];
  const cv::Matx33d to_global = G * ToMatx(s.frames.front().frame_to_patch);
  std::vector<cv::Point2d> q;
  for (const cv::Point2d c : {cv::Point2d(0, 0), cv::Point2d(w, 0), cv::Point2d(w, h), cv::Point2d(0, h)})
    q.push_back(ApplyHomography(to_global, c));
  double area = 0;
  for (size_t i = 0; i < 4; ++i) area += q[i].x * q[(i + 1) % 4].y - q[(i + 1) % 4].x * q[i].y;
  const double a = cv::norm(q[0] - q[1]) / cv::norm(q[3] - q[2]), b = cv::norm(q[1] - q[2]) / cv::norm(q[0] - q[3]);
  FirstFrameShape f;
  f.scale = std::sqrt(std::abs(area) / 2 / (w * h));
  f.uneven = std::max({a, 1 / a, b, 1 / b});
  return f;
}

// Why a patch placed through its link is not to be trusted ("" when it is). A downward camera
// draws a patch's first frame about the size of the patch before's first frame and as a
// near-rectangle (altitude and tilt change little over one patch): a link that makes it more than
// twice or less than half that size, or one side half as long again as the opposite one, chains
// homographies fitted to ground they do not describe (uncalibrated frames over a reef drew nine
// frames 20,000 px long). `align` places such a patch from its frames.
std::string LinkProblem(const cv::Matx33d& G, const PatchSidecar& s, const std::optional<FirstFrameShape>& before) {
  const auto mine = FirstFrameUnder(G, s);
  if (!mine || !before) return "";
  const double scale = mine->scale / before->scale;
  if (std::isfinite(scale) && scale <= 2 && scale >= 0.5 && std::isfinite(mine->uneven) && mine->uneven <= 1.5) return "";
  char why[240];
  std::snprintf(why, sizeof why, "its link to patch %d draws its first frame %.2f times the size of that patch's first "
                "frame, with sides %.2f times the opposite ones (at most 2 and 1.5 for a downward camera)",
                s.link->previous_patch, scale, mine->uneven);
  return why;
}

// Why a patch cannot be drawn ("" when it can): an image that does not open or disagrees with its
// sidecar, or a placement that is not finite, folds the patch, or sends part of it to infinity.
// On success the patch's image is left open in `image`.
std::string PlacementProblem(const cv::Matx33d& G, const PatchSidecar& s, const std::string& path,
                             const std::shared_ptr<TileCache>& cache, std::shared_ptr<const TiledImage>* image) {
  for (double v : G.val)
    if (!std::isfinite(v)) return "its placement is not finite";
  const double w = double(s.size[0]), h = double(s.size[1]);
  for (const cv::Vec3d& c : {cv::Vec3d(0, 0, 1), cv::Vec3d(w, 0, 1), cv::Vec3d(0, h, 1), cv::Vec3d(w, h, 1)})
    if ((G * c)[2] <= 1e-9) return "its placement sends part of it to infinity (degenerate homography)";
  const double det = G(0, 0) * G(1, 1) - G(0, 1) * G(1, 0);
  if (!(std::abs(det) > 1e-6 && std::abs(det) < 1e6)) return "its placement is degenerate (scale " + std::to_string(det) + ")";
  try {
    *image = std::make_shared<const TiledImage>(TiledImage::Open(path, cache));
    if ((*image)->width() != s.size[0] || (*image)->height() != s.size[1])
      return "its image is " + std::to_string((*image)->width()) + " x " + std::to_string((*image)->height()) +
             " but its sidecar says " + std::to_string(s.size[0]) + " x " + std::to_string(s.size[1]);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// The split of a sharded compose, recorded by its first shard: what every later shard and the
// finish must agree with. Created with link(2), which is atomic on local and network file systems.
// Returns the number of shards of the split (`shards` 0: whatever the plan says).
int CheckPlan(const std::string& partial, const std::string& fingerprint, int shards, long long chunks, bool create) {
  namespace fs = std::filesystem;
  const std::string path = (fs::path(partial) / "plan.json").string();
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    if (!create) Fail(partial, "holds no shards: no shard of this compose has run (plan.json is missing)");
    fs::create_directories(partial, ec);
    const nlohmann::json plan = {{"fingerprint", fingerprint}, {"shards", shards}, {"chunks", chunks},
                                 {"created", static_cast<long long>(std::time(nullptr))}};
    const std::string tmp = TemporarySibling(path);
    WriteFileAtomic(tmp, plan.dump() + "\n");
    const int rc = ::link(tmp.c_str(), path.c_str());  // fails if another shard was first: fine
    (void)rc;
    fs::remove(tmp, ec);
  }
  const nlohmann::json plan = nlohmann::json::parse(ReadSmallFile(path, 1 << 20), nullptr, false);
  if (plan.is_discarded() || !plan.contains("fingerprint") || !plan.contains("shards"))
    Fail(path, "is not a compose plan; delete " + partial + " to split the compose anew");
  char when[64] = "?";
  const std::time_t t = plan.value("created", 0LL);
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S UTC", std::gmtime(&t));
  if (plan["fingerprint"].get<std::string>() != fingerprint)
    Fail(partial, std::string("was split into shards on ") + when +
                      " for other patches, placements or options than the store has now (the store changed "
                      "since the split); its shards cannot be mixed with new ones: delete that folder to split anew");
  const int planned = plan["shards"].get<int>();
  if (shards != 0 && planned != shards)
    Fail(partial, "was split into " + std::to_string(planned) + " shards on " + when + ", not " + std::to_string(shards));
  if (planned < 1) Fail(path, "names no shards");
  return planned;
}

// One finish at a time: a lock file made with O_EXCL, naming its host and process. A lock left by
// a dead process on this host is taken over; one from another host must be deleted by hand.
class FinishLock {
 public:
  explicit FinishLock(const std::string& partial) : path_((std::filesystem::path(partial) / "finish.lock").string()) {
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    for (int attempt = 0; attempt < 2; ++attempt) {
      const int fd = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
      if (fd >= 0) {
        const std::string me = std::string(host) + " " + std::to_string(::getpid()) + " " + std::to_string(std::time(nullptr)) + "\n";
        const ssize_t n = ::write(fd, me.data(), me.size());
        (void)n;
        ::close(fd);
        return;
      }
      std::string text;
      try {
        text = ReadSmallFile(path_, 4096);
      } catch (const Error&) {
      }
      std::istringstream in(text);
      std::string other_host;
      long long pid = 0, since = 0;
      in >> other_host >> pid >> since;
      if (attempt == 0 && other_host == host && pid > 0 && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
        ::unlink(path_.c_str());  // its process is gone
        continue;
      }
      Fail(path_, "another finish of this compose is running (host " + other_host + ", process " + std::to_string(pid) +
                      "); if it died on another machine, delete this file");
    }
  }
  ~FinishLock() { ::unlink(path_.c_str()); }
  FinishLock(const FinishLock&) = delete;
  FinishLock& operator=(const FinishLock&) = delete;

 private:
  std::string path_;
};

}  // namespace

namespace {

// 1. Every patch that can be placed, in global pixels: its aligned placement, or its link to the
//    patch before it; the others are left out with the reason.
std::vector<PlacedPatch> PlacePatches(const Store& store, const std::shared_ptr<TileCache>& cache,
                                      std::map<int, cv::Matx33d>* to_global, ComposeResult* result) {
  std::vector<PlacedPatch> placed;
  std::map<int, std::optional<FirstFrameShape>> first_frames;  // placed patches' first frames
  for (const auto& entry : store.patches()) {
    PatchSidecar s;
    try {
      s = store.ReadSidecar(entry.id);
    } catch (const Error& e) {
      result->left_out.emplace_back(entry.id, e.what());
      continue;
    }
    cv::Matx33d G;
    if (s.patch_to_global) {
      G = ToMatx(*s.patch_to_global);
    } else if (s.link && to_global->count(s.link->previous_patch)) {
      G = (*to_global)[s.link->previous_patch] * ToMatx(s.link->to_previous);
      if (const std::string why = LinkProblem(G, s, first_frames[s.link->previous_patch]); !why.empty()) {
        result->left_out.emplace_back(entry.id, why + "; left out until the map is aligned, not guessed");
        continue;
      }
    } else if (to_global->empty()) {
      G = cv::Matx33d::eye();  // the first patch defines the global frame
    } else {
      result->left_out.emplace_back(entry.id, "not linked to the patches before it (tracking was "
                                             "lost before it started); left out, not guessed");
      continue;
    }
    PlacedPatch p;
    p.id = entry.id;
    p.path = (std::filesystem::path(store.dir()) / entry.image).string();
    const std::string problem = PlacementProblem(G, s, p.path, cache, &p.image);
    if (!problem.empty()) {
      result->left_out.emplace_back(entry.id, problem + "; left out");
      continue;
    }
    p.to_mosaic = G;  // global for now; the mosaic's offset and scale come next
    p.size = cv::Size(static_cast<int>(s.size[0]), static_cast<int>(s.size[1]));
    // Aligned frames each have their own placement: the patch goes piecewise, keyframe by
    // keyframe (the frames blended into it).
    const bool per_frame = s.aligned.value_or(false) && s.frame_size && !s.frames.empty() &&
                           std::all_of(s.frames.begin(), s.frames.end(), [](const FrameRecord& f) {
                             return f.frame_to_global.has_value() || !f.is_keyframe();
                           });
    if (per_frame) {
      const cv::Point2d c(((*s.frame_size)[0] - 1) / 2.0, ((*s.frame_size)[1] - 1) / 2.0);
      for (const auto& f : s.frames) {
        if (!f.is_keyframe()) continue;
        const cv::Matx33d F = ToMatx(*f.frame_to_global);
        p.local.push_back({F * ToMatx(f.frame_to_patch).inv(), ApplyHomography(F, c)});
      }
      p.local_sigma = 0.35 * std::max((*s.frame_size)[0], (*s.frame_size)[1]);
    }
    (*to_global)[entry.id] = G;
    first_frames[entry.id] = FirstFrameUnder(G, s);
    placed.push_back(p);
  }
  return placed;
}

// 2. The mosaic's frame: the patches' union moved to the origin and scaled to fit max_pixels;
//    the patches' placements move into it. Returns the shift of global pixels (full resolution).
cv::Matx33d FitMosaicFrame(const Store& store, const ComposeOptions& options, std::vector<PlacedPatch>* placed,
                           ComposeResult* result) {
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const auto& p : *placed) {
    const cv::Rect2d b = WarpedBounds(p.to_mosaic, p.size);
    x0 = std::min(x0, b.x), y0 = std::min(y0, b.y);
    x1 = std::max(x1, b.x + b.width), y1 = std::max(y1, b.y + b.height);
  }
  double scale = 1.0;
  const double full = (x1 - x0) * (y1 - y0);
  if (options.max_pixels > 0 && full > options.max_pixels) scale = std::sqrt(options.max_pixels / full);
  result->scale = scale;
  result->width = std::max(1LL, static_cast<long long>(std::floor((x1 - x0) * scale)));
  result->height = std::max(1LL, static_cast<long long>(std::floor((y1 - y0) * scale)));
  if (result->width > (1LL << 31) - 1 || result->height > (1LL << 31) - 1)
    Fail(store.dir(), "the patches span " + std::to_string(result->width) + " x " + std::to_string(result->height) +
                          " pixels, beyond a TIFF's 2^31; is a homography degenerate? (a pixel limit, max_pixels, scales it down)");
  // global -> mosaic pixel: shift the union to the origin, then scale about pixel centres.
  const cv::Matx33d O(1, 0, -x0 - 0.5, 0, 1, -y0 - 0.5, 0, 0, 1);
  const cv::Matx33d S(scale, 0, 0.5 * scale - 0.5, 0, scale, 0.5 * scale - 0.5, 0, 0, 1);
  for (auto& p : *placed) {
    p.to_mosaic = S * O * p.to_mosaic;
    p.bounds = WarpedBounds(p.to_mosaic, p.size);
    for (auto& l : p.local) {
      l.to_mosaic = S * O * l.to_mosaic;
      l.centre = ApplyHomography(S * O, l.centre);
    }
    if (!p.local.empty()) {  // the pieces may reach a little past the single placement
      const double grow = 8 + 0.02 * std::max(p.bounds.width, p.bounds.height);
      p.bounds = cv::Rect2d(p.bounds.x - grow, p.bounds.y - grow, p.bounds.width + 2 * grow, p.bounds.height + 2 * grow);
      p.local_sigma *= scale;
    }
  }
  return O;
}

// 2b. Exposure across the map: each patch's gain so that overlapping patches agree (read at 1/16
//     of full resolution; the gains average 1, so the map keeps its brightness).
void MatchPatchExposure(std::vector<PlacedPatch>* placed, double scale) {
  constexpr double kGainScale = 1.0 / 16;
  std::vector<cv::Mat> small;
  std::vector<cv::Matx33d> to_mosaic;
  for (const auto& p : *placed) {
    const int level = p.image->LevelForScale(kGainScale);
    const auto& L = p.image->info().levels[static_cast<size_t>(level)];
    cv::Mat img = p.image->ReadRegion(level, cv::Rect(0, 0, int(L.width), int(L.height)));
    if (img.channels() != 4) cv::cvtColor(img, img, img.channels() == 3 ? cv::COLOR_BGR2BGRA : cv::COLOR_GRAY2BGRA);
    cv::resize(img, img, cv::Size(std::max(1, int(std::lround(p.size.width * kGainScale))),
                                  std::max(1, int(std::lround(p.size.height * kGainScale)))), 0, 0, cv::INTER_AREA);
    small.push_back(img);
    to_mosaic.push_back(cv::Matx33d(1.0 / scale, 0, 0, 0, 1.0 / scale, 0, 0, 0, 1) * p.to_mosaic);
  }
  const std::vector<double> gains = SolveExposureGains(small, kGainScale, to_mosaic, 0.05);
  for (size_t k = 0; k < placed->size(); ++k) (*placed)[k].gain = gains[k];
}

// 3. The mosaic, chunk by chunk on all cores, journaled so that an interrupted run resumes.
//    false: a shard's chunks are written and the finish does the rest.
bool RenderMosaic(const Store& store, const ComposeOptions& options, const std::vector<PlacedPatch>& placed,
                  ComposeResult* result, const ProgressFn& progress) {
  PixelLayout layout;
  layout.width = result->width;
  layout.height = result->height;
  layout.channels = 4;
  const std::string partial = store.MosaicPath() + ".partial";
  const std::string fingerprint = Fingerprint(placed, *result, options);
  QuadtreeOptions qo;
  qo.threads = options.threads;
  qo.chunk_px = options.chunk_px;
  qo.block_px = std::min(qo.block_px, options.chunk_px);
  std::string part;
  std::unique_ptr<FinishLock> lock;
  const bool sharded = options.shards > 0 || options.finish;
  if (sharded) {
    qo.shard = options.shard - 1;
    qo.stage = options.finish ? QuadtreeOptions::Stage::kFinish : QuadtreeOptions::Stage::kChunks;
    const long long chunks = QuadtreeChunks(layout.width, layout.height, options.tiff, qo);
    qo.shards = CheckPlan(partial, fingerprint, options.shards, chunks, /*create=*/!options.finish);
    if (options.finish) {
      lock = std::make_unique<FinishLock>(partial);
      part = "finish";
    } else {
      part = "shard-" + std::to_string(options.shard) + "-of-" + std::to_string(options.shards);
      for (long long c = 0; c < chunks; ++c) result->shard_chunks += ShardOfChunk(c, qo.shards) == qo.shard;
    }
  }
  TileJournal journal(partial, fingerprint, options.restart, part);
  // Shards' files stay whole until the finish has written the file (a finish that dies is re-run).
  journal.set_free_while_writing(!sharded);
  result->discarded = journal.discarded();
  const PatchBlender blender(placed, result->scale, options.feather_px, options.bands);
  const QuadtreeStats q = BuildQuadtreePyramid(
      store.MosaicPath(), layout, options.tiff, qo, [&](const cv::Rect& r) { return blender.Render(r); },
      journal, progress);
  result->chunks = q.chunks;
  result->chunks_resumed = q.chunks_resumed;
  result->chunks_rendered = q.chunks_rendered;
  result->patches_used = static_cast<int>(placed.size());
  if (sharded && !options.finish) return false;  // the finish does the rest
  journal.Remove();
  lock.reset();
  result->written = true;
  return true;
}

// 4. Where the patches went, in their sidecars, and the global record of Table I.
void RecordPlacements(Store& store, const std::vector<PlacedPatch>& placed, const std::map<int, cv::Matx33d>& to_global,
                      const cv::Matx33d& O, double scale, const ComposeResult& result) {
  for (const auto& p : placed) {
    PatchSidecar s = store.ReadSidecar(p.id);
    s.patch_to_global = ToArray9(O * to_global.at(p.id));  // full-resolution global pixels
    for (auto& f : s.frames)  // the frames' own placements move with it
      if (f.frame_to_global) f.frame_to_global = ToArray9(O * ToMatx(*f.frame_to_global));
    store.UpdateSidecar(s);
  }
  GlobalRecord global = store.global();
  global.size = {result.width, result.height};
  global.scale = scale;
  const PatchSidecar first = store.ReadSidecar(placed.front().id);
  const cv::Vec3d origin = placed.front().to_mosaic * ToMatx(first.first_homography) * cv::Vec3d(0, 0, 1);
  global.offset = {origin[0] / origin[2], origin[1] / origin[2]};
  store.SetGlobal(global);
}

}  // namespace

ComposeResult ComposeMosaic(Store store, const ComposeOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("compose", error);
  // Compose records the placements in the sidecars and the manifest: a mosaic engine writing the
  // store meanwhile would lose them, or compose the engine's newer patches from the manifest. So
  // it is refused while one writes, and reads the store again once it holds the lock. A shard
  // writes only its share of the partial mosaic: shards run side by side, the finish locks.
  std::unique_ptr<StoreWriterLock> lock;
  if (options.shards == 0 || options.finish) lock = LockStoreForChange(store, "rolamos compose");
  TileCacheOptions co;
  co.max_memory_mb = options.cache_mb;
  auto cache = std::make_shared<TileCache>(co);
  ComposeResult result;
  std::map<int, cv::Matx33d> to_global;
  std::vector<PlacedPatch> placed = PlacePatches(store, cache, &to_global, &result);
  if (placed.empty()) Fail(store.dir(), "has no patch that can be placed");
  const cv::Matx33d O = FitMosaicFrame(store, options, &placed, &result);
  if (options.exposure && placed.size() > 1) MatchPatchExposure(&placed, result.scale);
  result.patches_used = static_cast<int>(placed.size());
  if (!RenderMosaic(store, options, placed, &result, progress)) return result;
  cache->Invalidate(store.MosaicPath());
  RecordPlacements(store, placed, to_global, O, result.scale, result);
  return result;
}

ShardStatus ComposeShardStatus(const Store& store) {
  namespace fs = std::filesystem;
  ShardStatus st;
  const std::string partial = store.MosaicPath() + ".partial";
  const std::string path = (fs::path(partial) / "plan.json").string();
  std::error_code ec;
  if (!fs::exists(path, ec)) return st;
  const nlohmann::json plan = nlohmann::json::parse(ReadSmallFile(path, 1 << 20), nullptr, false);
  if (plan.is_discarded() || !plan.contains("fingerprint") || !plan.contains("shards") || !plan.contains("chunks"))
    Fail(path, "is not a compose plan");
  st.split = true;
  st.shards = plan["shards"].get<int>();
  st.chunks = plan["chunks"].get<long long>();
  const std::set<long long> done = TileJournal::DoneChunks(partial, plan["fingerprint"].get<std::string>());
  std::set<int> pending;
  for (long long c = 0; c < st.chunks; ++c)
    if (!done.count(c)) pending.insert(ShardOfChunk(c, st.shards) + 1);
  st.pending.assign(pending.begin(), pending.end());
  return st;
}

}  // namespace rolamos
