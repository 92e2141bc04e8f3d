#include "rolamos/tiled_image.hpp"

#include <OpenImageIO/imagecache.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <filesystem>

#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "raster/resample.h"
#include "raster/decoded_tiles.h"
#include "raster/tiff_inspect.h"
#include "raster/tiff_tile_reader.h"

namespace rolamos {

struct TiledImage::Impl {
  TiledImageInfo info;
  std::shared_ptr<TileCache> cache;
  OIIO::ustring name;
  // Per level: OpenImageIO's (subimage, miplevel) for that level.
  std::vector<std::pair<int, int>> oiio_index;
  // Tiled TIFFs: decoded by libtiff into the cache's own tiles (OpenImageIO's otherwise).
  std::unique_ptr<TiffTileReader> tiff;
  uint64_t file_id = 0;
  void ReadTiles(int level, const cv::Rect& region, cv::Mat& out) const;
};

void TiledImage::Impl::ReadTiles(int level, const cv::Rect& region, cv::Mat& out) const {
  DecodedTiles& tiles = *cache->tiles_;
  const int tw = tiff->tile_width(level), th = tiff->tile_height(level);
  struct Piece {
    int tx, ty;
    std::shared_ptr<const cv::Mat> tile;
  };
  std::vector<Piece> pieces;
  std::vector<size_t> missing;
  for (int ty = region.y / th; ty <= (region.y + region.height - 1) / th; ++ty)
    for (int tx = region.x / tw; tx <= (region.x + region.width - 1) / tw; ++tx) {
      pieces.push_back({tx, ty, tiles.Find(file_id, level, tx, ty)});
      if (!pieces.back().tile) missing.push_back(pieces.size() - 1);
    }
  // The tiles not held are decoded on every core (libtiff's handles are one per thread).
  std::vector<std::exception_ptr> failed(missing.size());
  const auto decode = [&](const cv::Range& range) {
    for (int k = range.start; k < range.end; ++k) {
      Piece& p = pieces[missing[size_t(k)]];
      try {
        p.tile = std::make_shared<const cv::Mat>(tiff->DecodeTile(level, p.tx, p.ty));
        tiles.Add(file_id, level, p.tx, p.ty, p.tile);
      } catch (...) {
        failed[size_t(k)] = std::current_exception();
      }
    }
  };
  if (missing.size() > 1) cv::parallel_for_(cv::Range(0, int(missing.size())), decode);
  else decode(cv::Range(0, int(missing.size())));
  for (const auto& e : failed)
    if (e) std::rethrow_exception(e);
  for (const Piece& p : pieces) {
    const cv::Rect in = cv::Rect(p.tx * tw, p.ty * th, tw, th) & region;
    (*p.tile)(cv::Rect(in.x - p.tx * tw, in.y - p.ty * th, in.width, in.height))
        .copyTo(out(cv::Rect(in.x - region.x, in.y - region.y, in.width, in.height)));
  }
}

namespace {


std::string OiioError(OIIO::ImageCache* ic) {
  std::string e = ic->geterror();
  return e.empty() ? "OpenImageIO gave no reason" : e;
}

}  // namespace

TiledImage TiledImage::Open(const std::string& path, std::shared_ptr<TileCache> cache) {
  if (!std::filesystem::exists(path)) Fail(path, "no such file");
  if (std::filesystem::is_directory(path)) Fail(path, "is a directory, not an image");
  if (!cache) cache = DefaultTileCache();
  auto impl = std::make_shared<Impl>();
  impl->cache = cache;
  impl->name = OIIO::ustring(std::filesystem::absolute(path).lexically_normal().string());
  TiledImageInfo& info = impl->info;
  info.path = path;
  auto* ic = static_cast<OIIO::ImageCache*>(cache->cache_);

  if (HasTiffSignature(path)) {
    // Structure and plausibility first, with libtiff's allocation caps; then OpenImageIO.
    TiffStructure s = InspectTiff(path);
    info.format = "tiff";
    info.bigtiff = s.bigtiff;
    const auto& d0 = s.directories[s.levels[0]];
    info.channels = d0.samples;
    info.bits = d0.bits;
    info.has_alpha = d0.has_alpha;
    info.compression = TiffCompressionName(d0.compression);
    if (d0.sample_format != 1 /* SAMPLEFORMAT_UINT */ || (d0.bits != 8 && d0.bits != 16))
      Fail(path, std::to_string(d0.bits) + "-bit samples of format " +
                     std::to_string(d0.sample_format) +
                     " are not read here (8 or 16-bit unsigned; use `rolamos convert`)");
    if (d0.samples > 4)
      Fail(path, std::to_string(d0.samples) + " samples per pixel; 1 to 4 are read");
    impl->tiff = TiffTileReader::TryOpen(impl->name.string(), s);
    int mip_levels = 1;
    if (impl->tiff) {
      impl->file_id = cache->tiles_->FileId(impl->name.string(), impl->tiff->stamp());
      if (impl->tiff->masked()) {
        info.channels = impl->tiff->channels();
        info.has_alpha = true;
        info.compression += "-mask";
      }
    } else {
      ic->get_image_info(impl->name, 0, 0, OIIO::ustring("miplevels"), OIIO::TypeInt, &mip_levels);
      const std::string open_error = ic->geterror();
      if (!open_error.empty()) Fail(path, open_error);
    }
    const bool as_mip = mip_levels == static_cast<int>(s.directories.size());
    for (int dir : s.levels) {
      const auto& d = s.directories[dir];
      LevelInfo l;
      l.width = d.width;
      l.height = d.height;
      l.tile_width = d.tiled ? static_cast<int>(d.tile_width) : 0;
      l.tile_height = d.tiled ? static_cast<int>(d.tile_height) : 0;
      info.levels.push_back(l);
      impl->oiio_index.emplace_back(as_mip ? 0 : dir, as_mip ? dir : 0);
    }
  } else {
    const OIIO::ImageSpec* spec = ic->imagespec(impl->name, 0, 0);
    if (!spec) Fail(path, "not an image OpenImageIO can read (" + OiioError(ic) + ")");
    info.format = spec->get_string_attribute("oiio:ImageFormat", "unknown");
    if (spec->format != OIIO::TypeDesc::UINT8 && spec->format != OIIO::TypeDesc::UINT16)
      Fail(path, "samples of type " + std::string(spec->format.c_str()) +
                     " are not read here (8 or 16-bit unsigned)");
    if (spec->nchannels < 1 || spec->nchannels > 4)
      Fail(path, std::to_string(spec->nchannels) + " channels; 1 to 4 are read");
    info.channels = spec->nchannels;
    info.bits = spec->format == OIIO::TypeDesc::UINT16 ? 16 : 8;
    info.has_alpha = spec->alpha_channel >= 0;
    info.compression = spec->get_string_attribute("compression", "");
    info.levels.push_back({spec->width, spec->height, 0, 0});
    impl->oiio_index.emplace_back(0, 0);
  }
  info.georef = ReadGeoref(path);
  TiledImage image;
  image.impl_ = impl;
  return image;
}

const TiledImageInfo& TiledImage::info() const { return impl_->info; }
const std::shared_ptr<TileCache>& TiledImage::cache() const { return impl_->cache; }

int TiledImage::cv_type() const {
  return CV_MAKETYPE(info().bits == 16 ? CV_16U : CV_8U, info().channels);
}

cv::Mat TiledImage::ReadRegion(int level, const cv::Rect& region) const {
  cv::Mat out(std::max(0, region.height), std::max(0, region.width), cv_type());
  ReadRegionInto(level, region, out);
  return out;
}

void TiledImage::ReadRegionInto(int level, const cv::Rect& region, cv::Mat& out, bool file_order) const {
  const auto& info = impl_->info;
  if (level < 0 || level >= num_levels())
    Fail(info.path, "level " + std::to_string(level) + " does not exist (levels 0.." +
                        std::to_string(num_levels() - 1) + ")");
  const LevelInfo& l = info.levels[static_cast<size_t>(level)];
  if (region.width <= 0 || region.height <= 0 || region.x < 0 || region.y < 0 ||
      region.x + static_cast<long long>(region.width) > l.width ||
      region.y + static_cast<long long>(region.height) > l.height)
    Fail(info.path, "region " + std::to_string(region.x) + "," + std::to_string(region.y) + "," +
                        std::to_string(region.width) + "," + std::to_string(region.height) +
                        " is outside level " + std::to_string(level) + " (" +
                        std::to_string(l.width) + "x" + std::to_string(l.height) + ")");
  CV_Assert(out.rows == region.height && out.cols == region.width && out.type() == cv_type());
  if (impl_->tiff) {
    impl_->ReadTiles(level, region, out);
  } else {
    ReadThroughOiio(level, region, out);
  }
  if (file_order) return;
  if (info.channels == 3) cv::cvtColor(out, out, cv::COLOR_RGB2BGR);
  if (info.channels == 4) cv::cvtColor(out, out, cv::COLOR_RGBA2BGRA);
}

void TiledImage::ReadThroughOiio(int level, const cv::Rect& region, cv::Mat& out) const {
  const auto& info = impl_->info;
  auto* ic = static_cast<OIIO::ImageCache*>(impl_->cache->cache_);
  const auto [subimage, miplevel] = impl_->oiio_index[static_cast<size_t>(level)];
  const OIIO::TypeDesc type = info.bits == 16 ? OIIO::TypeDesc::UINT16 : OIIO::TypeDesc::UINT8;
  if (!ic->get_pixels(impl_->name, subimage, miplevel, region.x, region.x + region.width,
                      region.y, region.y + region.height, 0, 1, 0, info.channels, type,
                      out.data, OIIO::AutoStride, static_cast<OIIO::stride_t>(out.step[0])))
    Fail(info.path, "level " + std::to_string(level) + " region " + std::to_string(region.x) +
                        "," + std::to_string(region.y) + "," + std::to_string(region.width) +
                        "," + std::to_string(region.height) +
                        " cannot be decoded: " + OiioError(ic));
}

int TiledImage::LevelForScale(double scale) const {
  int best = 0;
  for (int k = 1; k < num_levels(); ++k) {
    const double level_scale = double(info().levels[static_cast<size_t>(k)].width) / width();
    if (level_scale + 1e-9 >= scale) best = k;
  }
  return best;
}

cv::Mat TiledImage::ReadScaled(const cv::Rect& region0, double scale) const {
  if (region0.x < 0 || region0.y < 0 || region0.width <= 0 || region0.height <= 0 ||
      region0.x + static_cast<long long>(region0.width) > width() ||
      region0.y + static_cast<long long>(region0.height) > height())
    Fail(info().path, "region " + std::to_string(region0.x) + "," + std::to_string(region0.y) +
                          "," + std::to_string(region0.width) + "," +
                          std::to_string(region0.height) + " is outside the image (" +
                          std::to_string(width()) + "x" + std::to_string(height()) + ")");
  cv::Size out(std::max(1, static_cast<int>(std::lround(region0.width * scale))),
               std::max(1, static_cast<int>(std::lround(region0.height * scale))));
  return ReadResampled(region0.x, region0.y, scale, out);
}

cv::Mat TiledImage::ReadResampled(double x0, double y0, double scale, cv::Size out) const {
  if (!(scale > 0 && scale <= 1.0))
    Fail(info().path, "scale " + std::to_string(scale) + " is outside (0, 1]");
  const int level = LevelForScale(scale);
  const LevelInfo& l = info().levels[static_cast<size_t>(level)];
  const double fx = double(l.width) / width(), fy = double(l.height) / height();
  // Output pixel (i, j) covers level-0 [x0 + i/scale, x0 + (i+1)/scale); its centre in level
  // coordinates is u = (x0 + (i + 0.5)/scale) * fx - 0.5.
  const double ax = fx / scale, ay = fy / scale;
  const double bx = (x0 + 0.5 / scale) * fx - 0.5, by = (y0 + 0.5 / scale) * fy - 0.5;
  const double ux0 = bx, ux1 = bx + ax * (out.width - 1);
  const double uy0 = by, uy1 = by + ay * (out.height - 1);
  const bool exact = std::abs(ax - 1) < 1e-9 && std::abs(ay - 1) < 1e-9 &&
                     std::abs(bx - std::round(bx)) < 1e-6 && std::abs(by - std::round(by)) < 1e-6;
  if (exact && bx >= 0 && by >= 0 && std::round(ux1) < l.width && std::round(uy1) < l.height)
    return ReadRegion(level, cv::Rect(static_cast<int>(std::lround(bx)),
                                      static_cast<int>(std::lround(by)), out.width, out.height));
  // Shrinking by up to 2x: a light pre-filter keeps linear interpolation from aliasing. The
  // region read has margins wider than that filter, so windows read apart agree with one read.
  const double a = std::max(ax, ay);
  const double sigma = a > 1.0 ? 0.5 * std::sqrt(a * a - 1.0) : 0.0;
  const long long margin = 2 + static_cast<long long>(std::ceil(3 * sigma));
  const long long rx0 = std::clamp<long long>(static_cast<long long>(std::floor(ux0)) - margin, 0, l.width - 1);
  const long long ry0 = std::clamp<long long>(static_cast<long long>(std::floor(uy0)) - margin, 0, l.height - 1);
  const long long rx1 = std::clamp<long long>(static_cast<long long>(std::ceil(ux1)) + margin + 1, rx0 + 1, l.width);
  const long long ry1 = std::clamp<long long>(static_cast<long long>(std::ceil(uy1)) + margin + 1, ry0 + 1, l.height);
  cv::Mat pixels = ReadRegion(level, cv::Rect(static_cast<int>(rx0), static_cast<int>(ry0),
                                              static_cast<int>(rx1 - rx0),
                                              static_cast<int>(ry1 - ry0)));
  cv::Mat m = (cv::Mat_<double>(2, 3) << ax, 0, bx - rx0, 0, ay, by - ry0);
  return WarpRespectingAlpha(pixels, m, out, info().has_alpha, sigma);
}

}  // namespace rolamos
