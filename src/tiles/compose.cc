#include "rolamos/compose.hpp"

#include <cmath>
#include <filesystem>
#include <map>

#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "util/homography.h"

namespace rolamos {

bool ComposeOptions::IsValid(std::string* error) const {
  if (max_pixels < 0) {
    *error = "--max-pixels cannot be negative";
    return false;
  }
  if (feather_px < 1 || feather_px > 1024) {
    *error = "feather width must be 1..1024 pixels";
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


struct Placed {
  int id = 0;
  std::string path;
  std::shared_ptr<TiledImage> image;  // opened once, read band after band
  cv::Matx33d to_global;  // patch level-0 pixel -> global pixel (before offset and scale)
  cv::Size size;
  cv::Matx33d to_mosaic;  // patch level-0 pixel -> mosaic pixel
  cv::Rect2d bounds;      // in mosaic pixels
};


// How much coarser than the region the feather's distances are computed: the ramp is smooth,
// and the distance transform was a third of compose's time at full resolution.
int FeatherStep(int width) { return std::clamp(width / 8, 1, 4); }

// Weights that fall to zero at a patch's no-data border over `width` pixels (in the region read,
// whose origin is a multiple of FeatherStep so every band sees the same coarse grid).
cv::Mat FeatherFromAlpha(const cv::Mat& alpha, int width) {
  const cv::Mat inside = alpha > 127;
  const int f = FeatherStep(width);
  cv::Mat dist;
  if (f == 1) {
    cv::distanceTransform(inside, dist, cv::DIST_L2, 3);
  } else {
    // A coarse cell is inside only when all of it is; its distance, scaled back, is a slight
    // underestimate, so the ramp never reaches past the data.
    cv::Mat small, coarse;
    cv::resize(inside, small, cv::Size((alpha.cols + f - 1) / f, (alpha.rows + f - 1) / f), 0, 0, cv::INTER_AREA);
    cv::distanceTransform(small >= 255, coarse, cv::DIST_L2, 3);
    coarse *= static_cast<float>(f);
    cv::resize(coarse, dist, cv::Size(small.cols * f, small.rows * f), 0, 0, cv::INTER_LINEAR);
    dist = dist(cv::Rect(0, 0, alpha.cols, alpha.rows)).clone();
    dist.setTo(0, ~inside);
  }
  return cv::min(dist / static_cast<float>(width), 1.0f);
}

}  // namespace

ComposeResult ComposeMosaic(Store store, const ComposeOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("compose", error);
  TileCacheOptions co;
  co.max_memory_mb = options.cache_mb;
  auto cache = std::make_shared<TileCache>(co);
  ComposeResult result;

  // 1. Place the patches.
  std::vector<Placed> placed;
  std::map<int, cv::Matx33d> to_global;
  for (const auto& entry : store.patches()) {
    PatchSidecar s;
    try {
      s = store.ReadSidecar(entry.id);
    } catch (const Error& e) {
      result.left_out.emplace_back(entry.id, e.what());
      continue;
    }
    cv::Matx33d G;
    if (s.patch_to_global) {
      G = ToMatx(*s.patch_to_global);
    } else if (s.extra.contains("link") && to_global.count(s.extra["link"].value("previous_patch", -1))) {
      G = to_global[s.extra["link"]["previous_patch"].get<int>()] *
          ToMatx(s.extra["link"]["to_previous"].get<Homography>());
    } else if (to_global.empty()) {
      G = cv::Matx33d::eye();  // the first patch defines the global frame
    } else {
      result.left_out.emplace_back(entry.id, "not linked to the patches before it (tracking was "
                                             "lost before it started); left out, not guessed");
      continue;
    }
    Placed p;
    p.id = entry.id;
    p.path = (std::filesystem::path(store.dir()) / entry.image).string();
    p.to_global = G;
    p.size = cv::Size(static_cast<int>(s.size[0]), static_cast<int>(s.size[1]));
    to_global[entry.id] = G;
    placed.push_back(p);
  }
  if (placed.empty()) Fail(store.dir(), "has no patch that can be placed");

  // 2. The global frame: offset to the union of the patches, scale to fit max_pixels.
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const auto& p : placed) {
    const cv::Rect2d b = WarpedBounds(p.to_global, p.size);
    x0 = std::min(x0, b.x), y0 = std::min(y0, b.y);
    x1 = std::max(x1, b.x + b.width), y1 = std::max(y1, b.y + b.height);
  }
  double scale = 1.0;
  const double full = (x1 - x0) * (y1 - y0);
  if (options.max_pixels > 0 && full > options.max_pixels) scale = std::sqrt(options.max_pixels / full);
  result.scale = scale;
  result.width = std::max(1LL, static_cast<long long>(std::floor((x1 - x0) * scale)));
  result.height = std::max(1LL, static_cast<long long>(std::floor((y1 - y0) * scale)));
  // global -> mosaic pixel: shift the union to the origin, then scale about pixel centres.
  const cv::Matx33d O(1, 0, -x0 - 0.5, 0, 1, -y0 - 0.5, 0, 0, 1);
  const cv::Matx33d S(scale, 0, 0.5 * scale - 0.5, 0, scale, 0.5 * scale - 0.5, 0, 0, 1);
  for (auto& p : placed) {
    p.to_mosaic = S * O * p.to_global;
    p.bounds = WarpedBounds(p.to_mosaic, p.size);
  }

  // 3. Band by band: each patch that reaches the band is read (at the level its scale needs),
  // warped, and blended with weights that fade at patch borders.
  PixelLayout layout;
  layout.width = result.width;
  layout.height = result.height;
  layout.channels = 4;
  PyramidTiffWriter writer(store.MosaicPath(), layout, options.tiff);
  const int band_h = writer.band_height();
  cv::Mat acc_buffer, wsum_buffer;
  for (long long y = 0; y < result.height; y += band_h) {
    const int rows = static_cast<int>(std::min<long long>(band_h, result.height - y));
    const cv::Rect2d band(0, double(y), double(result.width), double(rows));
    // The band's sums, reused from band to band (fresh pages for every band cost a fifth of the
    // time in page faults).
    acc_buffer.create(band_h, static_cast<int>(result.width), CV_32FC3);
    wsum_buffer.create(band_h, static_cast<int>(result.width), CV_32F);
    cv::Mat acc = acc_buffer.rowRange(0, rows), wsum = wsum_buffer.rowRange(0, rows);
    acc.setTo(cv::Scalar::all(0));
    wsum.setTo(cv::Scalar::all(0));
    for (auto& p : placed) {
      if ((p.bounds & band).area() <= 0) continue;
      if (!p.image) p.image = std::make_shared<TiledImage>(TiledImage::Open(p.path, cache));
      const TiledImage& image = *p.image;
      // The band's footprint in the patch, with room for the feather.
      const cv::Matx33d from_mosaic = p.to_mosaic.inv();
      const cv::Rect2d need = WarpedBounds(from_mosaic * cv::Matx33d(1, 0, 0, 0, 1, double(y), 0, 0, 1),
                                     cv::Size(static_cast<int>(result.width), rows));
      const int level = image.LevelForScale(std::min(1.0, scale * 1.0001));
      const auto& L = image.info().levels[static_cast<size_t>(level)];
      const double fx = double(L.width) / image.width(), fy = double(L.height) / image.height();
      const double margin = options.feather_px * fx + 2;
      const int step = FeatherStep(std::max(1, static_cast<int>(options.feather_px * fx)));
      const int rx0 = std::max(0, static_cast<int>(std::floor(need.x * fx - margin)) / step * step);
      const int ry0 = std::max(0, static_cast<int>(std::floor(need.y * fy - margin)) / step * step);
      const int rx1 = std::min<int>(static_cast<int>(L.width), static_cast<int>(std::ceil((need.x + need.width) * fx + margin)));
      const int ry1 = std::min<int>(static_cast<int>(L.height), static_cast<int>(std::ceil((need.y + need.height) * fy + margin)));
      if (rx1 <= rx0 || ry1 <= ry0) continue;
      cv::Mat px = image.ReadRegion(level, cv::Rect(rx0, ry0, rx1 - rx0, ry1 - ry0));
      if (px.channels() != 4) cv::cvtColor(px, px, px.channels() == 3 ? cv::COLOR_BGR2BGRA : cv::COLOR_GRAY2BGRA);
      cv::Mat alpha;
      cv::extractChannel(px, alpha, 3);
      const cv::Mat weight = FeatherFromAlpha(alpha, std::max(1, static_cast<int>(options.feather_px * fx)));
      // Colour times weight in one pass.
      cv::Mat colour(px.size(), CV_32FC3);
      for (int r = 0; r < px.rows; ++r) {
        const cv::Vec4b* s4 = px.ptr<cv::Vec4b>(r);
        const float* w = weight.ptr<float>(r);
        cv::Vec3f* c = colour.ptr<cv::Vec3f>(r);
        for (int k = 0; k < px.cols; ++k) c[k] = cv::Vec3f(s4[k][0] * w[k], s4[k][1] * w[k], s4[k][2] * w[k]);
      }
      // region pixel -> patch level-0 pixel -> mosaic pixel -> band pixel
      const cv::Matx33d R(1 / fx, 0, (rx0 + 0.5) / fx - 0.5, 0, 1 / fy, (ry0 + 0.5) / fy - 0.5, 0, 0, 1);
      const cv::Matx33d B(1, 0, 0, 0, 1, -double(y), 0, 0, 1);
      // Only the part of the band the patch covers is warped (not the whole band width).
      const cv::Rect2d cover = p.bounds & band;
      const cv::Rect roi = cv::Rect(static_cast<int>(std::floor(cover.x)) - 1, static_cast<int>(std::floor(cover.y - y)) - 1,
                                    static_cast<int>(std::ceil(cover.width)) + 3, static_cast<int>(std::ceil(cover.height)) + 3) &
                           cv::Rect(0, 0, acc.cols, acc.rows);
      if (roi.empty()) continue;
      const cv::Matx33d T(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1);
      const cv::Mat M(T * B * p.to_mosaic * R);
      cv::Mat wc, ww;
      cv::warpPerspective(colour, wc, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
      cv::warpPerspective(weight, ww, M, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
      acc(roi) += wc;
      wsum(roi) += ww;
    }
    cv::Mat out(rows, static_cast<int>(result.width), CV_8UC4, cv::Scalar::all(0));
    for (int r = 0; r < rows; ++r) {
      const cv::Vec3f* a = acc.ptr<cv::Vec3f>(r);
      const float* w = wsum.ptr<float>(r);
      cv::Vec4b* o = out.ptr<cv::Vec4b>(r);
      for (int c = 0; c < out.cols; ++c) {
        if (w[c] <= 1e-4f) continue;
        const float k = 1.0f / w[c];
        o[c] = cv::Vec4b(cv::saturate_cast<uchar>(a[c][0] * k), cv::saturate_cast<uchar>(a[c][1] * k),
                         cv::saturate_cast<uchar>(a[c][2] * k), 255);
      }
    }
    writer.WriteBand(out);
    if (progress) progress(double(y + rows) / result.height);
  }
  writer.Finish();
  cache->Invalidate(store.MosaicPath());

  // 4. Record where the patches went and the global record of Table I.
  for (const auto& p : placed) {
    PatchSidecar s = store.ReadSidecar(p.id);
    s.patch_to_global = ToArray9(O * p.to_global);  // full-resolution global pixels
    store.UpdateSidecar(s);
  }
  GlobalRecord global = store.global();
  global.size = {result.width, result.height};
  global.scale = scale;
  const PatchSidecar first = store.ReadSidecar(placed.front().id);
  const cv::Vec3d origin = placed.front().to_mosaic * ToMatx(first.first_homography) * cv::Vec3d(0, 0, 1);
  global.offset = {origin[0] / origin[2], origin[1] / origin[2]};
  store.SetGlobal(global);
  result.patches_used = static_cast<int>(placed.size());
  return result;
}

}  // namespace rolamos
