#include "server/tile_pyramid.h"

#include <cmath>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace rolamos {

TilePyramid::TilePyramid(std::shared_ptr<TiledImage> image) : image_(std::move(image)) {
  const double side = double(std::max(image_->width(), image_->height()));
  max_level_ = static_cast<int>(std::ceil(std::log2(std::max(1.0, side))));
  const int zooms = side <= kTile ? 0 : static_cast<int>(std::ceil(std::log2(side / kTile)));
  xyz_shift_ = std::max(0, max_level_ - zooms);
}

cv::Size TilePyramid::LevelSize(int level) const {
  const double scale = std::ldexp(1.0, level - max_level_);
  return cv::Size(static_cast<int>(std::ceil(image_->width() * scale)),
                  static_cast<int>(std::ceil(image_->height() * scale)));
}

cv::Mat TilePyramid::Tile(int level, long long tx, long long ty) const {
  if (level < 0 || level > max_level_ || tx < 0 || ty < 0) return {};
  const double scale = std::ldexp(1.0, level - max_level_);
  const cv::Size size = LevelSize(level);
  if (tx * kTile >= size.width || ty * kTile >= size.height) return {};
  const int tw = static_cast<int>(std::min<long long>(kTile, size.width - tx * kTile));
  const int th = static_cast<int>(std::min<long long>(kTile, size.height - ty * kTile));
  return image_->ReadResampled(tx * kTile / scale, ty * kTile / scale, scale, cv::Size(tw, th));
}

std::vector<uchar> TilePyramid::Encode(cv::Mat tile, const std::string& ext, int jpeg_quality) {
  if (tile.depth() == CV_16U) tile.convertTo(tile, CV_8U, 1.0 / 257.0);
  std::vector<uchar> bytes;
  if (ext == "png") {
    cv::imencode(".png", tile, bytes, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } else if (ext == "webp") {
    if (tile.channels() == 2) cv::cvtColor(tile, tile, cv::COLOR_GRAY2BGRA);  // keeps alpha
    if (tile.channels() == 1) cv::cvtColor(tile, tile, cv::COLOR_GRAY2BGR);
    cv::imencode(".webp", tile, bytes, {cv::IMWRITE_WEBP_QUALITY, jpeg_quality});
  } else {
    if (tile.channels() == 4) cv::cvtColor(tile, tile, cv::COLOR_BGRA2BGR);
    if (tile.channels() == 2) cv::extractChannel(tile, tile, 0);
    cv::imencode(".jpg", tile, bytes, {cv::IMWRITE_JPEG_QUALITY, jpeg_quality});
  }
  return bytes;
}

std::string TilePyramid::DziDescriptor(const std::string& ext) const {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
         "<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\" Format=\"" + ext +
         "\" Overlap=\"0\" TileSize=\"" + std::to_string(kTile) + "\">\n  <Size Width=\"" +
         std::to_string(image_->width()) + "\" Height=\"" + std::to_string(image_->height()) +
         "\"/>\n</Image>\n";
}

std::vector<std::pair<std::string, std::string>> StoreImages(const Store& store) {
  std::vector<std::pair<std::string, std::string>> images;
  if (store.HasMosaic()) images.emplace_back("mosaic", store.MosaicPath());
  for (const auto& p : store.patches()) images.emplace_back("patch-" + std::to_string(p.id), store.ImagePath(p.id));
  return images;
}

bool TileEncodingIsValid(int jpeg_quality, double cache_mb, std::string* error) {
  if (jpeg_quality < 1 || jpeg_quality > 100) {
    *error = "JPEG quality " + std::to_string(jpeg_quality) + " is outside 1..100";
    return false;
  }
  TileCacheOptions c;
  c.max_memory_mb = cache_mb;
  return c.IsValid(error);
}

}  // namespace rolamos
